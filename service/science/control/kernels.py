"""Compiled per-sample control: discrete PID (paper eq. 19, filtered derivative, anti-windup),
command clamping, divergence watch, and the point-by-point runner that loops plant + controller.

Arrays per axis (row 0 = Y, row 1 = Z):
  pid_p[a] = (kp V/µm, ki V/(µm·s), kd V·s/µm, tf_s derivative filter, on 0/1,
              mode damping section b0, b1, b2, a1, a2: a biquad on the error, V/µm; all 0 = none)
  pid_s[a] = (integral V, derivative V, previous error µm, the damping section's two states V)
  lim[a]   = (v_min V, v_max V, max step V/sample, amplifier gain V/V)
  trip[a]  = (error limit µm, samples over the limit to trip, sensor range µm)
"""

from __future__ import annotations

import types

import numpy as np

from drivers.jit import drop_stale_caches, njit

KP, KI, KD, TF, ON, DB0, DB1, DB2, DA1, DA2, NPID = range(11)
S_INT, S_DER, S_EPREV, S_D1, S_D2, NPS = range(6)
L_VMIN, L_VMAX, L_STEP, L_GAIN, NL = range(5)
T_ERR, T_N, T_RANGE, NT = range(4)
OK, TRIP_ERROR, TRIP_RANGE, STOPPED = 0, 1, 2, 3
TRIP_REASONS = {TRIP_ERROR: "tracking error diverged", TRIP_RANGE: "sensor at the end of its range or lost"}
STOP_CHECK_SAMPLES = 32  # the runner polls its stop flag every this many samples (≤ 50)


@njit(cache=True)
def clamp_command(u, u_prev, vmin, vmax, step):
    """Clamp a command (V) to the rate limit around ``u_prev`` and to [vmin, vmax]."""
    u = min(max(u, u_prev - step), u_prev + step)
    return min(max(u, vmin), vmax)


@njit(cache=True)
def pid_step(p, s, e_um, u_ff, u_prev, vmin, vmax, step, dt):
    """One PID sample on error ``e_um``; returns the clamped total command (V) = u_ff + PID + the
    mode damping section's output.

    Derivative: backward-Euler filtered, D = (tf·D + kd·Δe)/(tf + dt). Anti-windup: conditional
    integration (the integrator does not move while the output is clamped and the error pushes
    further into the clamp), and the integral is bounded by the voltage span. Damping: a biquad
    (transposed direct form II) on the error (service.science.control.damping)."""
    if p[ON] < 0.5:
        return clamp_command(u_ff, u_prev, vmin, vmax, step)
    d = (p[TF] * s[S_DER] + p[KD] * (e_um - s[S_EPREV])) / (p[TF] + dt)
    s[S_DER] = d
    s[S_EPREV] = e_um
    damp = p[DB0] * e_um + s[S_D1]
    s[S_D1] = p[DB1] * e_um - p[DA1] * damp + s[S_D2]
    s[S_D2] = p[DB2] * e_um - p[DA2] * damp
    i_new = s[S_INT] + p[KI] * e_um * dt
    span = vmax - vmin
    i_new = min(max(i_new, -span), span)
    raw = u_ff + p[KP] * e_um + i_new + d + damp
    u = clamp_command(raw, u_prev, vmin, vmax, step)
    saturated_up = raw > u + 1e-12
    saturated_dn = raw < u - 1e-12
    if not ((saturated_up and e_um > 0.0) or (saturated_dn and e_um < 0.0)):
        s[S_INT] = i_new
    return u


def _runner(
    wargs,
    noise,
    n0,
    ref_um,
    uff_v,
    pid_p,
    pid_s,
    u_last,
    lim,
    trip,
    over,
    um_per_v,
    y_last,
    dt,
    x_out,
    u_out,
    ai,
    diag,
    stop,
):
    """The per-sample loop (see ``point_by_point_runner``). ``STEP``, the plant's compiled step, is
    a global of the function object compiled: this module's (the emulator's step, cached) or a copy
    of it with another step in its globals."""
    n = ref_um.shape[0]
    ao = np.zeros(2)
    for k in range(n):
        if k % STOP_CHECK_SAMPLES == 0 and stop[0] != 0:
            return k, STOPPED
        for a in range(2):
            e = ref_um[k, a] - y_last[a]
            u = pid_step(
                pid_p[a], pid_s[a], e, uff_v[k, a], u_last[a], lim[a, L_VMIN], lim[a, L_VMAX], lim[a, L_STEP], dt
            )
            u_last[a] = u
            u_out[k, a] = u
            ao[a] = u / lim[a, L_GAIN]
        STEP(
            wargs[0],
            wargs[1],
            wargs[2],
            wargs[3],
            wargs[4],
            wargs[5],
            wargs[6],
            wargs[7],
            wargs[8],
            wargs[9],
            wargs[10],
            ao[0],
            ao[1],
            noise,
            n0 + k,
            ai,
            0,
            diag,
        )
        status = OK
        for a in range(2):
            y = ai[0, a] * um_per_v[a]
            y_last[a] = y
            x_out[k, a] = y
            if not np.isfinite(y) or abs(y) >= trip[a, T_RANGE]:
                status = TRIP_RANGE
            if abs(ref_um[k, a] - y) > trip[a, T_ERR]:
                over[a] += 1.0
                if over[a] >= trip[a, T_N]:
                    status = TRIP_ERROR
            else:
                over[a] = 0.0
        if status != OK:
            return k + 1, status
    return n, OK


#: the plant step the cached runner compiles in: the first step whose DAQ names the files it compiles
#: from (``stepping_sources``: the emulated DAQ's, the compiled stepping hook the product has), set
#: before the runner's first call. Its runner is compiled into numba's cache once (a runner for any
#: other step is compiled per process: numba caches no closure and no function-typed argument,
#: numba/numba#2065, #6251). Set here, not imported, so that science loads no emulator.
STEP = None
# the GIL is free while a period runs: handlers and the loop do not stall each other
_CACHED_RUNNER = njit(cache=True, nogil=True)(_runner)


def point_by_point_runner(step_fn, cache_sources=None):
    """The compiled runner for one plant step function: the cached one for the step whose DAQ names
    ``cache_sources`` (the files the step compiles from: the emulator's), else one built and compiled
    once per process and plant.

    ``runner(wargs, noise, n0, ref_um, uff_v, pid_p, pid_s, u_last, lim, trip, over, um_per_v, y_last,
    dt, x_out, u_out, ai, diag, stop) -> (samples run, status)``: a causal loop over ``ref_um.shape[0]``
    samples, command k from the AI sample k-1, clamped, stepped through the plant; the error watch
    trips on divergence. ``u_last``, ``y_last``, ``over``, ``pid_s`` carry state across calls.
    ``stop`` (uint8[1], e.g. ``BenchSession.stop_flag``) is polled every STOP_CHECK_SAMPLES samples:
    non-zero returns STOPPED. The runner releases the GIL, so another thread can raise it mid-period."""
    global STEP
    if cache_sources and STEP is None:
        STEP = step_fn
        # numba keys the cache on this file alone: recompile the runner when the step's files change
        drop_stale_caches(globals(), cache_sources)
    if step_fn is STEP:
        return _CACHED_RUNNER
    key = id(step_fn)
    if key not in _RUNNERS:
        body = types.FunctionType(_runner.__code__, {**globals(), "STEP": step_fn}, "runner")
        _RUNNERS[key] = (step_fn, njit(nogil=True)(body))
    return _RUNNERS[key][1]


_RUNNERS: dict = {}


@njit(cache=True, nogil=True)
def watch_block(ref_um, x_um, trip, over):
    """The same divergence watch over a measured block (buffered mode): (first tripping sample+1, status)."""
    for k in range(ref_um.shape[0]):
        for a in range(2):
            y = x_um[k, a]
            if not np.isfinite(y) or abs(y) >= trip[a, T_RANGE]:
                return k + 1, TRIP_RANGE
            if abs(ref_um[k, a] - y) > trip[a, T_ERR]:
                over[a] += 1.0
                if over[a] >= trip[a, T_N]:
                    return k + 1, TRIP_ERROR
            else:
                over[a] = 0.0
    return ref_um.shape[0], OK
