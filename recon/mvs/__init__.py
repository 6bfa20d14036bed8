"""Dense multi-view stereo on the CPU: PatchMatch depth and normal maps (numba kernels).

``views.select_problems`` picks source views and depth ranges from a sparse model;
``stereo.photometric_view`` / ``stereo.geometric_view`` compute one view's maps in COLMAP's layout;
``patchmatch`` holds the algorithm; ``planar_fill`` gives untextured regions the plane around them;
``background`` takes the depths a surface's edge lent the sky beside it;
``colmap_io`` reads and writes COLMAP's ``.bin`` maps;
``bench`` measures speed and accuracy.

numba's compiler (llvmlite) must be loaded before pycolmap: with pycolmap 4.2.1's wheel loaded
first, numba's first compilation of a kernel (an empty or stale cache) corrupts the heap and aborts
the process; kernels loaded from numba's cache are unaffected. Importing this package loads llvmlite.
"""

import logging
import sys

if "pycolmap" in sys.modules and "llvmlite.binding" not in sys.modules:
    logging.getLogger(__name__).warning(
        "pycolmap was imported before numba: compiling the PatchMatch kernels may abort the process; "
        "import recon.mvs (or numba) before pycolmap")

import llvmlite.binding  # noqa: E402, F401  (load order: see above)
