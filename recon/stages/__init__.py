"""One module per stage; importing this package registers them, in pipeline order."""

import importlib

from recon.stage import REGISTRY

#: the order stages run in; a stage reads only from stages before it
ORDER = [
    "ingest", "calibrate", "preprocess", "features", "matching", "sfm", "export",
    "undistort", "mvs", "fusion", "mesh", "texture", "report",
    # side pipelines: each reads what it needs from the stages above (see pipelines/*.yaml)
    "localize",
    "stereo",
    "panorama",
]

for _name in ORDER:  # importing a stage module registers it
    importlib.import_module(f"recon.stages.{_name}")
for _name in ORDER:  # registry in pipeline order
    REGISTRY[_name] = REGISTRY.pop(_name)
