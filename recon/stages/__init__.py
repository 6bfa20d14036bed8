"""One module per stage; importing this package registers them, in pipeline order."""

from recon.stage import REGISTRY
from recon.stages import export, features, ingest, matching, sfm  # noqa: F401  (registers them)

#: the order stages run in; a stage reads only from stages before it
ORDER = ["ingest", "features", "matching", "sfm", "export"]

for _name in ORDER:  # re-insert in pipeline order (imports are sorted alphabetically)
    REGISTRY[_name] = REGISTRY.pop(_name)
