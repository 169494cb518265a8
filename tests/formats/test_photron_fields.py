"""Photron recordings as PFV 3 (.cih) and PFV 4 (.cihx) save them: colour decided from the camera model and the
pixels, Save Step / skipFrame and the trigger read into frame numbers and times, and field values fringelab does
not understand refused by name. Pixels are compared with pyMRAW frame by frame (pyMRAW reads no Save Step and no
colour type: it is the reference for the pixels only)."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.formats.container_common import UnsupportedRecording
from fringelab.formats.recordings import open_recording
from tests.formats.recording_files import write_cine, write_mraw, write_mraw_zip

pymraw = pytest.importorskip("pyMRAW")


def grey_frames(n: int, *, seed: int = 5) -> list[np.ndarray]:
    """12-bit frames of a mono sensor: a smooth scene with noise, no 2 × 2 pattern (phase means agree)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:32, 0:40]
    scene = 1350 + 200 * np.sin(xx / 7.0) * np.cos(yy / 9.0)
    return [np.clip(scene + rng.normal(0, 20, scene.shape), 0, 4095).astype(np.uint16) for _ in range(n)]


def bayer(frames: list[np.ndarray]) -> list[np.ndarray]:
    """The same scene through an RGGB mosaic under white light: green sites twice as bright as red and blue."""
    gain = np.tile(np.array([[0.5, 1.0], [1.0, 0.5]]), (16, 20))
    return [(frame * gain).astype(np.uint16) for frame in frames]


def test_pfv4_mono_camera_with_colour_type_raw_is_read_as_mono(tmp_path) -> None:
    """PFV4 writes <colorInfo><type>Raw</type> for a monochrome Nova S16: read, equal to pyMRAW frame by frame."""
    frames = grey_frames(3)
    header = write_mraw(tmp_path / "nova", frames, bits=12, header="cihx", colour="Raw", fps=20000,
                        camera="FASTCAM Nova S16 type 1100K-M-32GB")  # fmt: skip
    reference, _ = pymraw.load_video(str(header))
    with open_recording(header) as source:
        for i in range(3):
            np.testing.assert_array_equal(source[i], frames[i])
            np.testing.assert_array_equal(source[i], np.asarray(reference[i]))
        assert any("Color Type Raw read as mono: camera 'FASTCAM Nova S16" in note for note in source.notes)
    zipped = write_mraw_zip(tmp_path / "nova.zip", frames, bits=12, header="cihx", colour="Raw", camera="FASTCAM")
    with open_recording(zipped) as source:  # the pixels checked where they lie in the ZIP
        np.testing.assert_array_equal(source[2], frames[2])
        assert any("the camera model does not say, and the 2 × 2 pixel phases agree" in n for n in source.notes)


def test_raw_bayer_is_refused_with_what_to_save_instead(tmp_path) -> None:
    frames = grey_frames(2)
    colour_camera = write_mraw(tmp_path / "c", frames, bits=12, header="cihx", colour="Raw",
                               camera="FASTCAM Mini AX200 type 900K-C-16GB")  # fmt: skip
    with pytest.raises(UnsupportedRecording, match=r"raw Bayer data from a colour camera .*save the recording again "
                                                   r"as monochrome \(Color Type Mono"):  # fmt: skip
        open_recording(colour_camera)
    unnamed = write_mraw(tmp_path / "u", bayer(frames), bits=12, colour="Raw", camera="FASTCAM")
    mosaic = r"Color Type Raw: the camera model does not say whether it is colour, and the 2 × 2 pixel phases differ"
    with pytest.raises(UnsupportedRecording, match=mosaic + r" by \d+ % \(a Bayer mosaic\); in Photron"):
        open_recording(unnamed)
    mono_named = write_mraw(tmp_path / "m", bayer(frames), bits=12, colour="Raw")  # "-M-" model, mosaic pixels
    with pytest.raises(UnsupportedRecording, match=r"is monochrome by its name, but the 2 × 2 pixel phases differ"):
        open_recording(mono_named)
    flat = write_mraw(tmp_path / "f", frames, bits=12, colour="Raw", camera="FASTCAM")
    with open_recording(flat) as source:  # no model colour, no mosaic: mono
        np.testing.assert_array_equal(source[1], frames[1])


@pytest.mark.parametrize("header", ["cih", "cihx"])
def test_save_step_gives_frame_numbers_and_times(tmp_path, header) -> None:
    """Save Step 36 at 60 000 fps: frames 600 µs apart numbered 49300, 49336, … (not 16.7 µs and 49301)."""
    frames = grey_frames(4)
    path = write_mraw(tmp_path / "s", frames, bits=12, fps=60000, start_frame=49300, save_step=36, header=header)
    reference, _ = pymraw.load_video(str(path))
    with open_recording(path) as source:
        np.testing.assert_array_equal(source.frame_numbers, [49300, 49336, 49372, 49408])
        np.testing.assert_allclose(np.diff(source.frame_times_s), 600e-6, rtol=1e-12)
        np.testing.assert_allclose(source.frame_times_s[0], 49300 / 60000, rtol=1e-12)
        assert source.fps == pytest.approx(60000 / 36) and source.fps_header == 60000
        assert source.frame_names[1] == "frame 49336"
        for i in range(4):
            np.testing.assert_array_equal(source[i], np.asarray(reference[i]))


@pytest.mark.parametrize(
    ("fields", "refusal"),
    [
        ({"Trigger Mode": "Random 10"}, r"Trigger Mode 'Random 10': its frames are not one run"),
        ({"EffectiveBit Side": "Middle"}, r"EffectiveBit Side 'Middle' is not one fringelab knows"),
        ({"Edge Enhance": "On"}, r"Edge Enhance 'On': the camera software sharpened the pixels"),
        ({"Correct Trigger Frame": 5}, r"Correct Trigger Frame 5: fringelab does not know how it shifts"),
        ({"Save Step": "two"}, r"'Save Step' is 'two', not a number"),
        ({"Color Type": "YUV"}, r"Color Type 'YUV' is not one fringelab knows"),
    ],
)
def test_field_values_not_understood_are_refused_by_name(tmp_path, fields, refusal) -> None:
    path = write_mraw(tmp_path / "x", grey_frames(2), bits=12, fields=fields)
    with pytest.raises(ValueError, match=r"x\.cih: " + refusal):
        open_recording(path)


def test_cine_rate_shown_from_its_time_stamps_with_the_header_beside(tmp_path) -> None:
    """A header of 90 000 fps over time stamps 9 000 Hz apart: the recording's rate is 9 000, the header's beside."""
    pims = pytest.importorskip("pims")
    frames = [np.full((8, 8), 10 * i, np.uint8) for i in range(5)]
    path = write_cine(tmp_path / "r.cine", frames, fps=90000, stamp_fps=9000, first_image_no=-1)
    reference = pims.Cine(str(path))
    try:
        with open_recording(path) as source:
            expected = [reference.get_time_to_trigger(i) for i in range(5)]
            np.testing.assert_allclose(source.frame_times_s, expected, atol=1e-6)  # pims goes through µs
            assert reference.frame_rate == 90000 == source.fps_header
            assert source.fps == pytest.approx(9000, rel=1e-6)
            assert any("from the frame times (median step); the header states 90000" in n for n in source.notes)
    finally:
        reference.close()
