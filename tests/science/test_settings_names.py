"""Settings carry their units in their names; documents written under the former names still read."""

from fringelab.science.fringes import EdgeSettings


def test_edge_settings_read_under_their_former_names() -> None:
    former = {"min_contrast": 15.0, "saturation_level": 240.0, "edge_smoothing_px": 2.0, "min_edge_length_px": 5,
              "max_link_step_px": 1.0, "axis": "rows"}  # fmt: skip
    settings = EdgeSettings.from_dict(former)
    assert (settings.min_contrast_grey, settings.saturation_grey, settings.edge_smoothing_lines) == (15.0, 240.0, 2.0)
    assert (settings.min_edge_length_lines, settings.max_link_step_px_per_line, settings.axis) == (5, 1.0, "rows")
    assert EdgeSettings.from_dict({"min_contrast_grey": 15.0}) == EdgeSettings(min_contrast_grey=15.0)
