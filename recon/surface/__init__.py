"""Surfaces from dense points or depth maps, and their textures.

- :func:`recon.surface.poisson.poisson_mesh`: screened Poisson on oriented points, trimmed to the data.
- :func:`recon.surface.tsdf.tsdf_mesh`: depth maps fused in a TSDF, marching cubes.
- :func:`recon.surface.cleanup.clean_mesh`: degenerate/duplicate faces, non-manifold parts, small pieces,
  quadric decimation.
- :func:`recon.surface.texture.texture_mesh`: view selection, seam levelling, atlas baking.
- :mod:`recon.surface.export`: GLB, OBJ + MTL + PNG, vertex-coloured PLY.

Options: :class:`recon.surface.options.MeshOptions`, :class:`recon.surface.options.TextureOptions`.
Cameras are any objects with ``K``, ``R``, ``t`` in COLMAP's convention (e.g.
:class:`recon.eval.groundtruth.Camera`).
"""
