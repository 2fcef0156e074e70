"""The error model every sensor channel shares: scale, bias (constant, turn-on, random walk,
Gauss–Markov), white noise, saturation and quantization.

For a channel sampled at ``f`` Hz (period ``T = 1/f``) with ideal samples ``x_k`` the output is

.. math::

    y_k = Q\\big(\\operatorname{sat}\\big((1 + s)\\,x_k + b + b_0 + w_k + g_k + v_k\\big)\\big)

with ``s`` the scale-factor error, ``b`` a fixed bias, ``b_0 ~ N(0, bias_std^2)`` a turn-on bias drawn
once per run, ``w_k = w_{k-1} + N(0, bias_walk^2 T)`` a bias random walk (rate random walk, units
/sqrt(s)), ``g_k = a g_{k-1} + sqrt(1 - a^2) N(0, gm_std^2)`` with ``a = exp(-T / gm_tau_s)`` a first-order
Gauss–Markov error (GNSS multipath/atmosphere-like correlated error), and ``v_k ~ N(0, sigma^2)`` the
white noise. ``sigma`` is either ``noise_std`` directly or ``noise_density * sqrt(f)``: a noise
density ``N`` [unit/sqrt(Hz)] averaged over one sample period has variance ``N^2 / T`` (the
Allan-variance convention, IEEE Std 952). ``sat`` clips to ``±range`` and ``Q`` rounds to multiples of
``resolution``.

Every component draws from its own stream (see :func:`stream`), so switching one on or off never
changes the draws of another.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

from roadtruth.harness.files.strict_yaml import Fields

#: Keys of a channel-error block in a preset.
ERROR_KEYS: tuple[str, ...] = ("noise_std", "noise_density", "bias", "bias_std", "bias_walk", "gm_std",
                               "gm_tau_s", "scale_error", "resolution", "range")


@dataclass(frozen=True)
class ChannelErrors:
    """Error parameters of one group of channels (units of the channel; 0 = off)."""

    noise_std: float = 0.0        # white noise per sample [unit]
    noise_density: float = 0.0    # white noise density [unit/sqrt(Hz)]; sigma = density * sqrt(rate)
    bias: float = 0.0             # fixed bias [unit]
    bias_std: float = 0.0         # turn-on bias, drawn once per run [unit]
    bias_walk: float = 0.0        # bias random walk [unit/sqrt(s)]
    gm_std: float = 0.0           # Gauss–Markov correlated error, stationary std [unit]
    gm_tau_s: float = 1.0         # its correlation time [s]
    scale_error: float = 0.0      # scale-factor error [1] (0.01 = +1 %)
    resolution: float = 0.0       # quantization step [unit]
    range: float = 0.0            # saturation at ±range [unit]

    def white_std(self, rate_hz: float) -> float:
        """Standard deviation of the white noise of one sample at ``rate_hz`` [unit]."""
        return self.noise_std if self.noise_std > 0 else self.noise_density * math.sqrt(rate_hz)

    @property
    def is_ideal(self) -> bool:
        return self == ChannelErrors(gm_tau_s=self.gm_tau_s)


def parse_channel_errors(f: Fields) -> ChannelErrors:
    """Read one channel-error block (all figures ``>= 0`` except ``bias``); unknown keys are errors."""
    nonneg = {k: f.number(k, 0.0, lo=0.0) for k in ("noise_std", "noise_density", "bias_std", "bias_walk",
                                                   "gm_std", "resolution", "range")}
    if nonneg["noise_std"] > 0 and nonneg["noise_density"] > 0:
        raise f.fail("noise_std", "give noise_std or noise_density, not both")
    errors = ChannelErrors(
        bias=f.number("bias", 0.0),
        gm_tau_s=f.number("gm_tau_s", 1.0, lo=0.0, lo_open=True),
        scale_error=f.number("scale_error", 0.0, lo=-0.5, hi=0.5),
        **nonneg,
    )
    f.done()
    return errors


def stable_key(name: str) -> int:
    """A process-independent integer for a name (``hash()`` is salted per process; CRC-32 is not)."""
    return zlib.crc32(name.encode("utf-8"))


def stream(seed: int, *names: str) -> np.random.Generator:
    """The random stream of one (sensor, channel, component) key under a run seed.

    ``SeedSequence(seed, spawn_key=...)`` gives statistically independent streams per key; the key is
    derived from names only, so a stream does not depend on which other sensors are configured.
    """
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=tuple(stable_key(n) for n in names)))


#: Up to this many samples the Gauss–Markov recursion runs as a Python loop (well under the 0.4 s
#: that importing ``scipy.signal`` costs); longer channels use ``scipy.signal.lfilter``.
GM_LOOP_MAX_SAMPLES = 20_000


def gauss_markov_filter(drive: np.ndarray, a: float, g0: float) -> np.ndarray:
    """``g_k = a g_{k-1} + drive_k`` with ``a g_{-1} = g0`` (the first-order filter 1 / (1 - a z^-1)).

    Bit-identical to ``scipy.signal.lfilter([1], [1, -a], drive, zi=[g0])`` (its transposed direct
    form computes ``g_k = drive_k + z``, ``z = a g_k`` in the same order), so short channels need not
    import ``scipy.signal`` at all. [unit of ``drive``]
    """
    if drive.size > GM_LOOP_MAX_SAMPLES:
        from scipy.signal import lfilter

        return lfilter([1.0], [1.0, -a], drive, zi=[g0])[0]
    out = np.empty(drive.size)
    z = float(g0)
    for i, x in enumerate(drive.tolist()):
        g = x + z
        out[i] = g
        z = a * g
    return out


def apply_channel_errors(x: np.ndarray, errors: ChannelErrors, rate_hz: float, seed: int,
                         key: tuple[str, ...]) -> np.ndarray:
    """Apply the error model of the module docstring to ideal samples.

    Parameters
    ----------
    x : (n,) array [unit]
        Ideal samples at ``rate_hz`` (NaN stays NaN: the sample is missing).
    errors : ChannelErrors
    rate_hz : float
        Sample rate of ``x`` [Hz].
    seed : int
        Run seed.
    key : tuple of str
        (sensor, channel) naming the streams.

    Returns
    -------
    (n,) float64 array [unit]
    """
    n = x.size
    T = 1.0 / rate_hz
    y = (1.0 + errors.scale_error) * x.astype(np.float64) + errors.bias
    if errors.bias_std > 0:
        y = y + errors.bias_std * stream(seed, *key, "turn_on_bias").standard_normal()
    if errors.bias_walk > 0:
        steps = errors.bias_walk * math.sqrt(T) * stream(seed, *key, "bias_walk").standard_normal(n)
        y = y + np.cumsum(steps)
    if errors.gm_std > 0:
        a = math.exp(-T / errors.gm_tau_s)
        w = stream(seed, *key, "gauss_markov").standard_normal(n + 1)
        drive = errors.gm_std * math.sqrt(1.0 - a * a) * w[1:]
        # Start in the stationary distribution so the error is statistically the same at every sample.
        y = y + gauss_markov_filter(drive, a, a * errors.gm_std * w[0])
    sigma = errors.white_std(rate_hz)
    if sigma > 0:
        y = y + sigma * stream(seed, *key, "white").standard_normal(n)
    if errors.range > 0:
        y = np.clip(y, -errors.range, errors.range)
    if errors.resolution > 0:
        y = np.round(y / errors.resolution) * errors.resolution
    return y
