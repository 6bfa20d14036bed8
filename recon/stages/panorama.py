"""panorama: the ingested photos, taken by a camera turning about its centre -> one panorama image.

Writes ``panorama.jpg`` and ``panorama.json``: projection, size, scale and each stitched photo's
camera (focal length, principal point, camera-to-panorama rotation: enough to map directions to
pixels, see :meth:`recon.panorama.PanoramaModel.from_dict`); per photo its exposure gain, inlier
count, or why it could not be stitched; the matched pairs with their residuals before and after
bundle adjustment; the time each step took.
The work is :mod:`recon.panorama`; see pipelines/panorama.yaml.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from recon.files import write_json
from recon.panorama import PanoramaError, PanoramaOptions, stitch
from recon.products import Panorama as PanoramaProduct
from recon.products import Photos
from recon.stage import Stage, StageContext, StageError, register


@register
class PanoramaStage(Stage):
    name = "panorama"
    version = 1
    Config = PanoramaOptions
    requires = (Photos,)
    produces = PanoramaProduct
    summary = "stitch photos from a rotating camera into a spherical, cylindrical or plane panorama"

    def run(self, ctx: StageContext, cfg: PanoramaOptions) -> dict:
        photos = ctx.input(Photos)
        listing = photos.listing()
        entries = listing["images"]
        folder = photos.images
        images = [np.asarray(Image.open(folder / e["name"]).convert("RGB")) for e in entries]
        try:
            pano = stitch(images, cfg, [e.get("focal_px") for e in entries], [e["name"] for e in entries])
        except PanoramaError as exc:
            raise StageError(f"panorama: {exc}") from None
        reg, model = pano.registration, pano.model
        Image.fromarray(pano.image).save(ctx.out / "panorama.jpg", quality=95)
        inliers = np.zeros(len(entries), int)
        for pair in reg.pairs:
            inliers[[pair.i, pair.j]] += pair.inliers
        photos = []
        for k, entry in enumerate(entries):
            info = {"name": entry["name"], "stitched": k in reg.connected, "inliers": int(inliers[k])}
            if k in reg.connected:
                a = reg.connected.index(k)
                info.update(camera=a, gain=[round(g, 4) for g in pano.gains[a].tolist()])
            else:  # the library logged it
                info["reason"] = reg.dropped[k]
            photos.append(info)
        write_json(ctx.out / "panorama.json", {
            "convention": "cameras[photo.camera]: focal and principal point in pixels of the photo, rotation "
                          "camera-to-panorama (x right, y down, z forward); pixel centres at +0.5. "
                          "recon.panorama.PanoramaModel.from_dict(this) maps directions to pixels",
            **model.as_dict(),
            "focal": float(np.median(reg.focals)),
            "photos": photos,
            "pairs": [{"a": entries[p.i]["name"], "b": entries[p.j]["name"], "matches": p.matches,
                       "inliers": p.inliers, "confidence": round(p.confidence, 3),
                       "residual_before_px": round(p.residual_before, 3),
                       "residual_after_px": round(p.residual_after, 3)} for p in reg.pairs],
            "timings_s": {k: round(v, 3) for k, v in {**reg.timings, **pano.timings}.items()},
        })
        return {"photos": len(entries), "stitched": len(reg.connected), "dropped": len(reg.dropped),
                "size": f"{model.width}x{model.height}", "focal": round(float(np.median(reg.focals)), 1),
                "full_circle": model.full_circle}
