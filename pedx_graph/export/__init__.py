"""Results out: meshes, overlays, top views and animations of fitted tracks (``pedx-graph export``).

One job per module: :mod:`.camera` (one rectified camera: projection, its Jacobian, image files),
:mod:`.raster` (meshes painted into an image), :mod:`.meshes` (PLY / OBJ per frame), :mod:`.overlays`
(fits and 2D labels drawn on the camera images), :mod:`.topview` (a track seen from above in the level frame
of the derived ground), :mod:`.animation` (a GIF per track), :mod:`.run` (the whole export of a results
folder) and :mod:`.cli` (the command).
"""
