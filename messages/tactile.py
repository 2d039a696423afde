"""Tactile messages: the stimulus at every sample point, and one intensity per motor."""
from .base import Array, Float, Message, doc


class TactileField(Message):
    """The stimulus at every sample point of the hand (topic tactile/field; paper eq. 1, 2, 7)."""

    positions: Array(None, 3) = doc("sample points c_i in screen coordinates")
    l: Array(None, finite=False) = doc(  # noqa: E741 - the paper's name
        "l_i, distance from the sample to the object's front along the ray (eq. 7), screen units; "
        "NaN where the ray misses or the sample is outside the screen")
    s: Array(None) = doc("s_i, normalised relative strength (eq. 1), 0..1")
    h: Array(None) = doc("h_i, strength after the sharpness adjustment (eq. 2)")
    alpha: Float = doc("gradient constant of eq. 1, per screen unit")
    beta: Float = doc("reducing constant of eq. 2, 0..1")
    gamma: Float = doc("intensity per unit strength, eq. 3")

    def check(self):
        n = len(self.positions)
        for name in ("l", "s", "h"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name}: expected {n} values, one per sample, got {len(getattr(self, name))}")


class MotorCommand(Message):
    """One intensity per motor (topic tactile/motors; paper eq. 3, V_i = gamma h_i)."""

    names: list[str] = doc("motor names, as in the glove config")
    intensity: Array(None) = doc("V_i per motor, >= 0; the motor node maps it to PWM duty")

    def check(self):
        if len(self.names) != len(self.intensity):
            raise ValueError(f"intensity: expected {len(self.names)} values, one per name, got {len(self.intensity)}")
        values = self.intensity
        # a glove's few motors: min() of the values as floats is quicker than numpy's reduction
        if len(values) and (min(values.tolist()) if len(values) <= 64 else values.min()) < 0:
            raise ValueError("intensity: expected values >= 0")


class MotorCommands(Message):
    """What a served page played over one batch of its frames (topic tactile/played): one row of
    intensities per pose it computed the touch of (its own tactile pass, eq. 3)."""

    names: list[str] = doc("motor names, as in the glove config")
    source_stamps: Array(None) = doc("the time of the pose each row was computed from, the server's clock, seconds")
    intensity: Array(None, None) = doc("V per motor (columns) and pose (rows), >= 0, as played")

    def check(self):
        rows, cols = self.intensity.shape
        if rows != len(self.source_stamps) or (rows and cols != len(self.names)):
            raise ValueError(f"intensity: expected {len(self.source_stamps)} x {len(self.names)} values (a row per "
                             f"stamp, a column per name), got {rows} x {cols}")
        if rows and self.intensity.min() < 0:
            raise ValueError("intensity: expected values >= 0")
