"""Two-view stereo: a calibrated pair (or two posed photos) -> rectification, disparity by semi-global
matching (OpenCV's StereoSGBM) with a left-right consistency check, depth = f B / d as camera z of the
left photo in its own (unrectified) frame, a coloured point cloud.

``calibration``: the pair's geometry and its file format; ``rectify``: rectification and the
matching frame; ``disparity``: SGBM both ways and the left-right check; ``depth``: the whole chain
(:func:`stereo_depth`); ``outputs``: depth files and the PLY; ``pairs``: pairs from a sparse model.
"""

from recon.stereo.calibration import StereoCalibration, from_poses, read_calibration, write_calibration
from recon.stereo.depth import StereoDepth, stereo_depth
from recon.stereo.options import StereoOptions

__all__ = ["StereoCalibration", "StereoDepth", "StereoOptions", "from_poses", "read_calibration", "stereo_depth",
           "write_calibration"]
