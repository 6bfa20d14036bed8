"""Dense multi-view stereo on the CPU: PatchMatch depth and normal maps (numba kernels).

``views.select_problems`` picks source views and depth ranges from a sparse model;
``stereo.photometric_view`` / ``stereo.geometric_view`` compute one view's maps in COLMAP's layout;
``patchmatch`` holds the algorithm; ``colmap_io`` reads and writes COLMAP's ``.bin`` maps.

llvmlite (numba's compiler) must be loaded before pycolmap: with pycolmap 4.2.1's wheel loaded first,
numba's first compilation corrupts the heap and aborts the process. Importing this package loads it.
"""

import llvmlite.binding  # noqa: F401  (load order: see above)
