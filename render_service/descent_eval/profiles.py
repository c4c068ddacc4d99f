"""Evaluation protocols: which trajectories, trials, frames and modes are run."""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from board.descent.runner import MODES
from board.errors import InvalidInputError


@dataclass(frozen=True)
class Profile:
    """A protocol: trajectories (ids 1..10), trials per trajectory, frames per trial (None: the whole
    trajectory), filter modes, the terrain spec and the base seed of the simulator."""

    name: str
    trajectories: tuple[int, ...]
    trials: int
    frames: int | None
    modes: tuple[str, ...] = tuple(MODES)
    terrain: str = "procedural:europa:1"
    seed: int = 0

    def __post_init__(self) -> None:
        bad = [m for m in self.modes if m not in MODES]
        if bad:
            raise InvalidInputError(f"modes {bad}: use {', '.join(MODES)}")
        if self.trials < 1 or not self.trajectories:
            raise InvalidInputError("a profile needs at least one trajectory and one trial")
        if self.frames is not None and self.frames < 3:
            raise InvalidInputError(f"--frames {self.frames}: at least 3 frames (E is a line fit)")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["trajectories"] = list(self.trajectories)
        d["modes"] = list(self.modes)
        return d


PROFILES: dict[str, Profile] = {
    # two short trajectories, three trials: minutes (exercised by the tests)
    "ci": Profile("ci", trajectories=(1, 3), trials=3, frames=8),
    # the memorandum's protocol: ten trajectories x thirty trials, whole trajectories
    "paper": Profile("paper", trajectories=tuple(range(1, 11)), trials=30, frames=None),
}


def get_profile(name: str, *, trajectories: tuple[int, ...] | None = None, trials: int | None = None,
                frames: int | None = None, modes: tuple[str, ...] | None = None) -> Profile:
    """The named profile with optional overrides (a subset of the protocol)."""
    if name not in PROFILES:
        raise InvalidInputError(f"profile {name!r}: use one of {', '.join(PROFILES)}")
    kw = {k: v for k, v in dict(trajectories=trajectories, trials=trials, frames=frames, modes=modes).items()
          if v is not None}
    return replace(PROFILES[name], **kw)
