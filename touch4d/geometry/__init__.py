"""4D geometry shared by every node (paper §4.1-4.4, §5.2).

polytope (convex 4-polytopes and their boundary), shapes (the catalog), rotation (plane rotations,
poses, the controller mapping), projection (to the 3D screen), raycast (entry distances along +w),
visibility (culling, clip units, front/behind, hidden-region subtraction), quaternion (3D rotations of
one pose at a time, closed forms in numpy, shared by tracking and tactile), scene (YAML files and
scene/state messages), cli (`touch4d shape ...`).
"""
