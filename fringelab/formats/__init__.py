"""File formats: one module per file type, its writer and its reader together.

camera          camera-calibration JSON (and the OpenCV YAML export)
containers      the recording containers (the list of formats, sniffing, the ingest budget), checked without
                decoding frames; one module a container: container_zip (a ZIP or folder of frames),
                container_tiff, container_video (AVI, MP4), container_cine (Phantom .cine), container_mraw
                (Photron .cih/.cihx + .mraw); what they share (errors, byte reads) in container_common
recordings      frame sources of every container (lazy), and writing recordings of frames
sidecars        the sidecars z.csv, frames.csv, board.json (one parser each)
previews        the preview store of a recording (previews.h5)
projector       the projector calibration (HDF5)
topography      the topography result (writer and reader) and its XDMF views
edges           the stored edges of a chunk of frames, handed between a topography job's workers
simulations     opening a finite-element simulation (file or folder); one module per format: simulation_d3plot
                (lasso-python), simulation_vtu (.pvd/.vtu), simulation_exodus, simulation_csv (nodal and punch
                CSV), simulation_lsdyna_ascii (nodout, rcforc)
comparison      the comparison of a topography with a simulation (writer, reader)
procam          camera–projector calibrations (fringelab JSON; OpenCV FileStorage under SLStudio's or OpenCV's
                names)
patterns        the patterns.json sidecar of a coded (Gray-code) sequence
scan            camera–projector scan results (HDF5) and their points-csv and ply exports
exports         every export for other tools, of a topography result and of a comparison (one owner per format)
atomic, hdf5    the one atomic write, and the HDF5 conventions every result file follows

Modules the API imports (containers, previews, topography's reader) use numpy and h5py only; decoding frames
(recordings) and the OpenCV YAML export need OpenCV and are used by the worker and the command line.
"""

from typing import Literal, get_args

# The export formats, declared once (here, light to import: the command line's parser and the job spec use it).
ExportFormat = Literal["points-csv", "grid-npz", "mat", "vtk", "profile-csv"]
EXPORT_FORMATS: tuple[str, ...] = get_args(ExportFormat)
# The file each export job hands out, and its media type (vtk: the .pvd and its .vtu files in one ZIP).
EXPORT_FILES: dict[str, tuple[str, str]] = {
    "points-csv": ("topography.csv", "text/csv"),
    "profile-csv": ("topography-profile.csv", "text/csv"),
    "grid-npz": ("topography.npz", "application/octet-stream"),
    "mat": ("topography.mat", "application/x-matlab-data"),
    "vtk": ("topography-vtk.zip", "application/zip"),
}
# The exports of a camera–projector scan file (formats.scan), declared once.
ScanExport = Literal["points-csv", "ply"]
SCAN_EXPORT_FORMATS: tuple[str, ...] = get_args(ScanExport)
# The exports of a comparison file, declared once.
ComparisonExport = Literal["csv", "hdf5", "mat", "vtk", "profile-csv"]
COMPARISON_EXPORTS: tuple[str, ...] = get_args(ComparisonExport)
# The file each comparison export hands out (a comparison job's `format`, or an export job of a comparison).
COMPARISON_EXPORT_FILES: dict[str, tuple[str, str]] = {
    "csv": ("comparison.csv", "text/csv"),
    "hdf5": ("comparison-copy.h5", "application/x-hdf5"),
    "mat": ("comparison.mat", "application/x-matlab-data"),
    "vtk": ("comparison-vtk.zip", "application/zip"),
    "profile-csv": ("comparison-profile.csv", "text/csv"),
}
