"""How intensity renders are sampled (bpy-free: the constants and what the manifests record).

Cycles' adaptive sampling: every pixel gets ``samples`` rays, and the pixels whose noise estimate is still
above :data:`ADAPTIVE_THRESHOLD` get up to :data:`ADAPTIVE_MAX_FACTOR` times more.  The pixels that straddle
the skyline are the noisiest of a view (a sky/ground coverage estimated from a few rays), so they get the
extra rays; plain sky stops at ``samples``.  On Aristoteles 43 (Moon, 1800 px panoramas) 8 -> up to
32 rays cut the clean look's median extraction error from 0.013 to 0.009 deg, for 2.5 times the render time
of 8 rays everywhere (the regolith's texture is noisy enough to take most ground pixels to the maximum too;
32 rays everywhere cost 4 times; docs/benchmarks.md, session 10; ``python -m benchmarks.bench_render_sampling``).
Binary renders are not sampled this way: their pixels are exact centre rays.
"""
from __future__ import annotations

#: Noisy pixels get up to this many times the requested samples.
ADAPTIVE_MAX_FACTOR = 4
#: Cycles' adaptive-sampling noise threshold (its default).
ADAPTIVE_THRESHOLD = 0.01


def sampling_meta(samples: int, *, binary: bool = False) -> dict:
    """What a manifest records of the sampling of a render with ``samples`` requested per pixel."""
    if binary:
        return {"samples": 1, "adaptive": False}
    return {"samples": int(samples), "samples_max": int(samples) * ADAPTIVE_MAX_FACTOR, "adaptive": True,
            "adaptive_threshold": ADAPTIVE_THRESHOLD}


__all__ = ["ADAPTIVE_MAX_FACTOR", "ADAPTIVE_THRESHOLD", "sampling_meta"]
