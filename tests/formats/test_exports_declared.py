"""The export formats are declared once (fringelab.formats) and every place that offers them takes that list."""

import typing

from fringelab.commands.topography import register
from fringelab.core.specs import ComparisonSpec, ExportSpec
from fringelab.formats import COMPARISON_EXPORT_FILES, COMPARISON_EXPORTS, EXPORT_FILES, EXPORT_FORMATS


def _literals(annotation: object) -> list[set[str]]:
    """The sets of values of the Literal types in an annotation (through unions and Annotated)."""
    if typing.get_origin(annotation) is typing.Literal:
        return [set(typing.get_args(annotation))]
    if typing.get_origin(annotation) is typing.Annotated:
        return _literals(typing.get_args(annotation)[0])
    return [found for arg in typing.get_args(annotation) for found in _literals(arg)]


def test_every_export_format_has_its_file_and_is_offered_everywhere() -> None:
    assert set(EXPORT_FILES) == set(EXPORT_FORMATS)
    assert set(COMPARISON_EXPORT_FILES) == set(COMPARISON_EXPORTS)
    # an export job exports a topography or a comparison: each in its own formats
    assert _literals(ExportSpec.model_fields["format"].annotation) == [set(EXPORT_FORMATS), set(COMPARISON_EXPORTS)]
    assert _literals(ComparisonSpec.model_fields["format"].annotation) == [set(COMPARISON_EXPORTS)]
    import argparse

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    export = parser.parse_args(["export", "r.h5", "--format", EXPORT_FORMATS[-1], "-o", "x"])
    assert export.format == EXPORT_FORMATS[-1]
