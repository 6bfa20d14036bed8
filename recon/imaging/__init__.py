"""2D image operations: the preprocessing toolbox, video keyframes and camera calibration.

- :mod:`~recon.imaging.ops`: the registry of per-image operations (``OPS``) and ``apply_chain``;
  each operation lives in a module named for what it does (resize, undistort, denoise, contrast,
  deblur).
- :mod:`~recon.imaging.hdr`: grouping and merging exposure brackets.
- :mod:`~recon.imaging.masks`: COLMAP-convention mask files.
- :mod:`~recon.imaging.video`: keyframe selection from video.
- :mod:`~recon.imaging.calibration`: chessboard / ChArUco calibration and a target renderer.
- :mod:`~recon.imaging.intrinsics`: the camera model these operations read and update.
"""
