"""The tactile model (paper §5): the glove (hand, samples, motors) and the stimulus, eq. 1-7.

    glove = load_glove()                                   # config/glove.yaml
    st = compute_stimulus(glove, scene.ray_caster(), position, quaternion_xyzw)
    st.V                                                   # one intensity per motor (eq. 3)
"""
from .glove import DEFAULT_GLOVE, Glove, load_glove
from .pose import PoseError
from .stimulus import Stimulus, compute_stimulus, no_stimulus

__all__ = ["DEFAULT_GLOVE", "Glove", "load_glove", "PoseError", "Stimulus", "compute_stimulus", "no_stimulus"]
