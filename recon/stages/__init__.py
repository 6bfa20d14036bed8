"""One module per stage; importing this package registers them, in pipeline order."""

from recon.stage import REGISTRY
from recon.stages import (  # noqa: F401  (registers them)
    calibrate,
    export,
    features,
    fusion,
    ingest,
    matching,
    mesh,
    mvs,
    preprocess,
    report,
    sfm,
    texture,
    undistort,
)

#: the order stages run in; a stage reads only from stages before it
ORDER = ["ingest", "calibrate", "preprocess", "features", "matching", "sfm", "export", "undistort", "mvs", "fusion", "mesh", "texture", "report"]

for _name in ORDER:  # re-insert in pipeline order (imports are sorted alphabetically)
    REGISTRY[_name] = REGISTRY.pop(_name)
