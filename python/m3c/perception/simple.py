"""Estimators that estimate nothing by design: gender neutral unless given, depth none unless configured."""

from __future__ import annotations

from m3c.perception.interfaces import GENDERS, DepthEstimator, GenderEstimator
from m3c.perception.registry import register
from m3c.perception.types import FrameContext, Person


@register("gender", "neutral")
class NeutralGender(GenderEstimator):
    """Every track is "neutral" (the body fit runs on the neutral model, as the thesis's HMR 2.0 stage does)."""

    def estimate(self, track_id: int, people: list[Person]) -> str:
        return "neutral"


@register("gender", "given")
class GivenGender(GenderEstimator):
    """Genders the user states per track id ({0: "female", 3: "male"}); others get `default`."""

    def __init__(self, genders: dict | None = None, default: str = "neutral"):
        self.genders = {int(k): str(v) for k, v in (genders or {}).items()}
        for value in list(self.genders.values()) + [default]:
            if value not in GENDERS:
                raise ValueError(f"gender must be one of {', '.join(GENDERS)}, got {value!r}")
        self.default = default

    def estimate(self, track_id: int, people: list[Person]) -> str:
        return self.genders.get(int(track_id), self.default)


@register("depth", "none")
class NoDepth(DepthEstimator):
    """No depth map: the VO then initialises its patch depths randomly (as DPVO does without one)."""

    def estimate(self, ctx: FrameContext):
        return None
