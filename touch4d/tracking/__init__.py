"""Tracking: where the hand and the controller are, and what the controller does to the 4D scene.

calibration   room (metres) <-> 3D screen (screen units), and the hand held on the controller
paths         scripted hand paths, pure functions of time (config/paths.yaml)
desktop       a hand steered by keyboard and mouse (its fingers curled by keys)
fingers       finger motions (curl, point, spread ...), pure functions of time (config/fingers.yaml)
vr            OpenVR poses and buttons -> touch4d values
outputs       the hand/pose and controller/state messages every tracker publishes
scene_control the scene node's logic: controller motion -> 4D rotation (paper §4.4), commands
"""
