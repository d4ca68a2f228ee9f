"""The camera room: cameras as data (records.py: Cameras, Pixels, the RaySpace a loader sets), the one ray caster
(caster.py) with COLMAP's distortion (distortion.py), camera algebra (algebra.py), rigid corrections of cameras and
their rays (corrections.py) and the similarity between camera sets with the camera errors after it (alignment.py).
A stage of its own, before the datasets that load cameras and cast their rays."""
