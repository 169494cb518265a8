"""The export formats are declared once (fringelab.formats) and every place that offers them takes that list."""

import typing

from fringelab.commands.topography import register
from fringelab.core.specs import ExportSpec
from fringelab.formats import EXPORT_FILES, EXPORT_FORMATS


def test_every_export_format_has_its_file_and_is_offered_everywhere() -> None:
    assert set(EXPORT_FILES) == set(EXPORT_FORMATS)
    assert set(typing.get_args(ExportSpec.model_fields["format"].annotation)) == set(EXPORT_FORMATS)
    import argparse

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    export = parser.parse_args(["export", "r.h5", "--format", EXPORT_FORMATS[-1], "-o", "x"])
    assert export.format == EXPORT_FORMATS[-1]
