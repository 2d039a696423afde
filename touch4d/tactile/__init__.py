"""The tactile model (paper §5): the glove (hand, samples, motors) and the stimulus, eq. 1-7.

    glove = load_glove()                                   # config/glove.yaml
    st = compute_stimulus(glove, scene.ray_caster(), position, quaternion_xyzw)
    st.V                                                   # one intensity per motor (eq. 3)
    st = compute_joint_stimulus(glove, caster, names, positions, orientations, "right")   # tracked joints
"""
from .glove import DEFAULT_GLOVE, Glove, load_glove
from .pose import PoseError
from .skeleton import JointsError
from .stimulus import Stimulus, compute_joint_stimulus, compute_stimulus, no_stimulus

__all__ = ["DEFAULT_GLOVE", "Glove", "load_glove", "PoseError", "JointsError", "Stimulus", "compute_stimulus",
           "compute_joint_stimulus", "no_stimulus"]
