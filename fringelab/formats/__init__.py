"""File formats: one module per file type, its writer and its reader together.

camera        camera-calibration JSON (and the OpenCV YAML export)
containers    what an uploaded recording container is (ZIP, TIFF, video, .cine), checked without decoding frames
recordings    frame sources of every container (lazy), and the sidecars z.csv, frames.csv, board.json
previews      the preview store of a recording (previews.h5)
topography    projector tables, topography results (writer and reader), exports, edge chunks

Modules the API imports (containers, previews, topography's reader) use numpy and h5py only; decoding frames
(recordings) and the OpenCV YAML export need OpenCV and are used by the worker and the command line.
"""
