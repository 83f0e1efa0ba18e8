"""The emulated world: parameter/state arrays built from a bench config, noise, faults.

``World`` owns every array the kernels read and write. Devices (devices.py) are thin views on
it. Noise comes from ``numpy.random.default_rng(seed)`` in fixed chunks of unit normals,
consumed in sample order, so a run is reproducible whatever its block partition and whatever
other emulators in the process do.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from drivers.emulated import kernels as K
from drivers.emulated.faults import WORLD_KINDS, FaultInjector
from drivers.emulated.output_log import OutputLog
from drivers.emulated.pacing import Pacer
from drivers.emulated.tables import bouc_wen_coefficients, everett_table, slip_elements
from drivers.interfaces import OutputAborted
from drivers.limits import stack_rating_v

AXES = ("y", "z")
NOISE_CHUNK = 1 << 16  # samples of noise generated at a time
IDLE_THRESHOLD_V = 0.010  # write_idle waits until |amplifier output| < 10 mV ...
IDLE_CAP_S = 0.020  # ... for at most 20 ms
FAULT_KINDS = WORLD_KINDS  # the kinds inject_fault takes (faults.py)


def _on(section: dict) -> float:
    """Effect size multiplier: 0 when disabled, else ``scale``."""
    return float(section["scale"]) if section["enabled"] else 0.0


class World:
    """Two-axis bench physics. ``run(ao)`` advances it by len(ao) samples."""

    def __init__(self, config: dict, seed: int):
        self.config = config
        self.seed = int(seed)
        self._rng = np.random.default_rng(self.seed)
        self._noise = self._rng.standard_normal((NOISE_CHUNK, K.NOISE_COLS))
        self._cursor = 0
        daq = config["daq"]
        self.range_v = float(daq["range_v"])
        self.bits = int(daq["resolution_bits"])
        self.lsb_v = 2 * self.range_v / 2**self.bits
        self.latency = int(round(daq["latency"]["samples"] * _on(daq["latency"])))
        self.pg = np.zeros(K.NG)
        self.sg = np.zeros(K.NSG)
        self.pa = np.zeros((2, K.NPA))
        self.sa = np.zeros((2, K.NSA))
        self.ring = np.zeros((max(self.latency, 1), 2))
        self.tp = np.zeros((2, K.STACK_DEPTH))
        self.ps = np.zeros((2, K.STACK_DEPTH))
        n_modes = [self._creep_modes(config["axes"][ax]["piezo"]["creep"]) for ax in AXES]
        m = max(1, max(len(t) for t, _ in n_modes))
        self.creep_tau_s = np.full((2, m), np.inf)
        self.cw = np.zeros((2, m))
        self.ca = np.zeros((2, m))
        self.cs = np.zeros((2, m))
        for a, (tau, w) in enumerate(n_modes):
            self.creep_tau_s[a, : len(tau)] = tau
            self.cw[a, : len(w)] = w
            self.pa[a, K.P_NCREEP] = len(tau)
        self._build_static()
        self.sample_rate_hz = 0.0
        self.set_sample_rate(float(daq["sample_rate_hz"]))
        self._injected: dict[str, dict[str, float | None]] = {k: {} for k in FAULT_KINDS}  # kind → axis → at_s
        self._saturation_offset_um = np.zeros(2)
        self.last_ao = np.zeros(2)  # last AO row written through run/step (DAQ volts)
        #: ``[daq] realtime = true``: blocks take wall time at the sample clock (see pacing.py)
        self.pacer = Pacer() if daq.get("realtime", False) else None
        self.last_diag = K.empty_diag(0)
        self._scratch_out = np.zeros((1, K.NOISE_COLS))
        self._scratch_diag = K.empty_diag(1)
        self._scratch_ao = np.zeros((1, 2))  # step's one AO row (V), for the buffered loop's kernel
        self.reset_state()
        self._compile()
        self.faults = FaultInjector(self, config.get("faults"))
        self.output_log = OutputLog(self, config.get("emulator"))

    def _compile(self) -> None:
        """Compile (or load from numba's cache) the run and idle kernels with zero-length calls, so
        the first run does not spend seconds compiling while the watchdog guards it."""
        self.run(np.zeros((0, 2)))
        K.run_idle(
            *self._kernel_args(), self._noise, self._cursor, 0, IDLE_THRESHOLD_V, self._scratch_out, self._scratch_diag
        )

    # ------------------------------------------------------------------ construction
    @staticmethod
    def _creep_modes(creep: dict):
        rate = float(creep["rate_per_decade"]) * _on(creep)
        if rate == 0.0:
            return np.zeros(0), np.zeros(0)
        decades = math.log10(creep["tau_max_s"] / creep["tau_min_s"])
        per = int(creep["modes_per_decade"])
        tau = np.logspace(math.log10(creep["tau_min_s"]), math.log10(creep["tau_max_s"]), int(round(decades * per)) + 1)
        return tau, np.full(len(tau), rate / per)

    def _build_static(self) -> None:
        """Parameters that do not depend on the sample period."""
        cfg, pg, pa = self.config, self.pg, self.pa
        amb = cfg["ambient"]
        pg[K.G_LSB_AO_V] = self.lsb_v * (_on(cfg["daq"]["quantisation"]) or 1.0)
        pg[K.G_LSB_AI_V] = pg[K.G_LSB_AO_V]
        pg[K.G_QUANT_ON] = 1.0 if cfg["daq"]["quantisation"]["enabled"] else 0.0
        pg[K.G_RANGE_V] = self.range_v
        pg[K.G_LATENCY] = self.latency
        pg[K.G_MON_RATIO] = cfg["daq"]["monitor_ratio_v_per_v"]
        pg[K.G_T0_C] = amb["temperature_c"]
        drift = _on(amb["drift"])
        pg[K.G_TRATE_C_PER_S] = amb["drift"]["rate_c_per_s"] * drift
        pg[K.G_TAMP_C] = amb["drift"]["cycle_amplitude_c"] * drift
        pg[K.G_TOMEGA_RAD_S] = 2 * math.pi / amb["drift"]["cycle_period_s"]
        coupling = cfg["coupling"]
        pa[0, K.C_FROM_OTHER] = coupling["y_from_z"] * _on(coupling)
        pa[1, K.C_FROM_OTHER] = coupling["z_from_y"] * _on(coupling)
        self.tables = []
        for a, ax in enumerate(AXES):
            c = cfg["axes"][ax]
            amp, pz, gauge = c["amplifier"], c["piezo"], c["gauge"]
            pa[a, K.A_GAIN] = amp["gain_v_per_v"]
            pa[a, K.A_VMIN_V] = amp["output_min_v"]
            pa[a, K.A_VMAX_V] = amp["output_max_v"]
            # a PZT stack's large-signal capacitance exceeds its rated (small-signal) one: the current
            # limit holds the stack's voltage to I/(factor·C), which the bench's own checks (on C) do not see
            pa[a, K.A_CAP_F] = amp["load_capacitance_f"] * amp.get("large_signal_capacitance_factor", 1.0)
            pa[a, K.A_NOISE_V] = amp["noise"]["rms_v"] * _on(amp["noise"])
            pa[a, K.A_FAULT_S] = amp["overcurrent_fault_s"]
            pa[a, K.A_OC_RESET_S] = amp["overcurrent_reset_s"]
            hyst = pz["hysteresis"]
            pa[a, K.P_DI_UM_PER_V] = pz["reversible_um_per_v"]
            pa[a, K.P_HYST_ON] = 1.0 if hyst["enabled"] else 0.0
            pa[a, K.P_LIN_UM_PER_V] = hyst["switched_um"] / hyst["reference_v"]
            asym = pz["asymmetry"]
            pa[a, K.P_Q_UM_PER_V2] = asym["electrostrictive_um_per_v2"] * _on(asym)
            pa[a, K.P_SAT_INV] = _on(asym) / asym["saturation_um"]
            temp = pz["temperature"]
            pa[a, K.P_TC_PER_C] = temp["gain_per_c"] * _on(temp)
            pa[a, K.P_TREF_C] = temp["reference_c"]
            depol = pz["depolarisation"]
            pa[a, K.P_DEPOL_LOSS] = depol["loss_fraction"] * _on(depol)
            pa[a, K.P_DEPOL_RATE] = 1.0 / depol["time_constant_s"]
            lo, hi, step = amp["output_min_v"] - 5.0, amp["output_max_v"] + 5.0, 0.5
            n = int(round((hi - lo) / step)) + 1
            pa[a, K.P_GRID_LO_V] = lo
            pa[a, K.P_GRID_INV_STEP] = 1.0 / step
            pa[a, K.P_GRID_N] = n
            self.tables.append(self._family_table(a, hyst, lo, step, n))
            rng_um = 10.0 * gauge["scale_um_per_v"]
            pa[a, K.S_V_PER_UM] = 1.0 / gauge["scale_um_per_v"]
            pa[a, K.S_RANGE_UM] = rng_um
            pa[a, K.S_NOISE_UM] = gauge["noise"]["rms_nm"] * 1e-3 * _on(gauge["noise"])
            pa[a, K.S_NL_UM] = gauge["nonlinearity"]["fraction_of_range"] * 2 * rng_um * _on(gauge["nonlinearity"])
            pickup = gauge["pickup"]
            pa[a, K.S_PICK_OMEGA] = 2 * math.pi * pickup["frequency_hz"]
            pa[a, K.S_PICK_UM] = pickup["amplitude_nm"] * 1e-3 * _on(pickup)
            pa[a, K.S_PICK3_UM] = pickup["third_harmonic_nm"] * 1e-3 * _on(pickup)
        size = max(t.shape[0] for t in self.tables)
        self.ev = np.zeros((2, size, size))
        for a, table in enumerate(self.tables):
            self.ev[a, : table.shape[0], : table.shape[1]] = table
        for a, ax in enumerate(AXES):  # switched strain for a virgin 0 -> reference_v excursion
            hyst = cfg["axes"][ax]["piezo"]["hysteresis"]
            s0 = K.switched_reset(self.pa, self.sa, self.tp, self.ps, self.ev, a, True, 0.0)
            s1 = K.switched_update(self.pa, self.sa, self.tp, self.ps, self.ev, a, float(hyst["reference_v"]))
            pa[a, K.P_KSW_UM] = hyst["switched_um"] * _on(hyst) / (s1 - s0)

    def _family_table(self, a: int, hyst: dict, lo_v: float, step_v: float, n: int) -> np.ndarray:
        """Set axis ``a``'s family parameters; return its table (the Everett function for Preisach,
        the elements' slip limits and weights in rows 0 and 1 for Maxwell-slip)."""
        family = hyst.get("family", "preisach")
        pa = self.pa
        pa[a, K.P_FAMILY] = K.FAMILIES.index(family)
        if family == "preisach":
            return everett_table(hyst, lo_v, step_v, n)
        if family == "bouc_wen":
            (pa[a, K.P_BW_A], pa[a, K.P_BW_BETA], pa[a, K.P_BW_GAMMA], pa[a, K.P_BW_N], pa[a, K.P_BW_STEP_V]) = (
                bouc_wen_coefficients(hyst["bouc_wen"])
            )
            return np.zeros((2, 2))
        limits_v, weights = slip_elements(hyst["maxwell_slip"])
        pa[a, K.P_MS_N] = len(limits_v)
        pa[a, K.P_MS_ELASTIC] = hyst["maxwell_slip"]["elastic_fraction"]
        table = np.zeros((len(limits_v), len(limits_v)))
        table[0], table[1] = limits_v, weights
        return table

    def set_sample_rate(self, rate_hz: float) -> None:
        """Recompute every coefficient that depends on the sample period (exact discretisations)."""
        dt = 1.0 / rate_hz
        self.sample_rate_hz = rate_hz
        cfg, pa = self.config, self.pa
        self.pg[K.G_DT_S] = dt
        for a, ax in enumerate(AXES):
            c = cfg["axes"][ax]
            amp, pz, flex, gauge = c["amplifier"], c["piezo"], c["flexure"], c["gauge"]
            pa[a, K.A_SLEW_DV] = amp["slew_limit_v_per_s"] * dt
            cap_f = amp["load_capacitance_f"] * amp.get("large_signal_capacitance_factor", 1.0)
            pa[a, K.A_CUR_DV] = amp["current_limit_a"] / cap_f * dt
            pa[a, K.A_BW_ALPHA] = self._lag_alpha(amp["bandwidth"], "bandwidth_hz", dt)
            pa[a, K.S_BW_ALPHA] = self._lag_alpha(gauge["bandwidth"], "bandwidth_hz", dt)
            rd = pz["rate_dependence"]
            tau = rd["relaxation_s"] * _on(rd)
            pa[a, K.P_RELAX_ALPHA] = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
            pa[a, K.P_RELAX_FRAC] = rd.get("relaxing_fraction", 1.0)
            self.ca[a] = -np.expm1(-dt / self.creep_tau_s[a])
            pa[a, K.S_DRIFT_UM] = gauge["drift"]["offset_rate_nm_per_s"] * 1e-3 * _on(gauge["drift"]) * dt
            dyn = flex["dynamics"]
            pa[a, K.F_ON] = 1.0 if dyn["enabled"] else 0.0
            if dyn["enabled"]:
                wn = 2 * math.pi * self.resonance_hz(ax)
                z = dyn["damping_ratio"]
                m = np.zeros((3, 3))
                m[0, 1] = 1.0
                m[1, 0], m[1, 1], m[1, 2] = -wn * wn, -2 * z * wn, wn * wn
                e = expm(m * dt)  # zero-order-hold discretisation of x'' + 2ζωx' + ω²x = ω²u
                pa[a, K.F_AD00], pa[a, K.F_AD01], pa[a, K.F_AD10], pa[a, K.F_AD11] = e[0, 0], e[0, 1], e[1, 0], e[1, 1]
                pa[a, K.F_BD0], pa[a, K.F_BD1] = e[0, 2], e[1, 2]

    @staticmethod
    def _lag_alpha(section: dict, key: str, dt: float) -> float:
        """First-order lag coefficient 1 - exp(-dt/τ); 1 (no lag) when the effect is off."""
        size = _on(section)
        if size == 0.0:
            return 1.0
        tau = size / (2 * math.pi * section[key])
        return 1.0 - math.exp(-dt / tau)

    def resonance_hz(self, axis: str) -> float:
        flex = self.config["axes"][axis]["flexure"]
        scale = flex["dynamics"]["scale"] if flex["dynamics"]["enabled"] else 1.0
        return float(flex["resonance_hz"]) / scale

    def reset_state(self) -> None:
        """Everything at rest at 0 V, time 0, memory as configured, faults cleared."""
        self.sg[:] = 0.0
        self.sg[K.SG_TEMP_C] = self.pg[K.G_T0_C]
        self.sa[:] = 0.0
        self.ring[:] = 0.0
        self.cs[:] = 0.0
        for a, ax in enumerate(AXES):
            hyst = self.config["axes"][ax]["piezo"]["hysteresis"]
            virgin = hyst["initial_state"] == "virgin"
            self.pa[a, K.P_S0] = K.switched_reset(
                self.pa, self.sa, self.tp, self.ps, self.ev, a, virgin, float(hyst["reference_v"])
            )
            self.sa[a, K.S_ENABLED] = 1.0
            self.sa[a, K.S_GOFF] = self.config["axes"][ax]["gauge"]["offset_um"]
        for kind in self._injected:
            self._injected[kind].clear()
        self._saturation_offset_um[:] = 0.0

    # ------------------------------------------------------------------ running
    def _kernel_args(self):
        return (self.pg, self.pa, self.sg, self.sa, self.ring, self.tp, self.ps, self.ev, self.ca, self.cw, self.cs)

    def _ensure_noise(self, n: int) -> None:
        while self._noise.shape[0] - self._cursor < n:
            self._noise = np.concatenate(
                [self._noise[self._cursor :], self._rng.standard_normal((NOISE_CHUNK, K.NOISE_COLS))]
            )
            self._cursor = 0

    def run(self, ao_daq_v: np.ndarray) -> np.ndarray:
        """Advance len(ao) samples with the given (n, 2) AO block; return the (n, 4) AI block."""
        ao = np.ascontiguousarray(ao_daq_v, dtype=np.float64)
        n = ao.shape[0]
        if self.pacer is not None:
            self.pacer.tick(n, self.sample_rate_hz)
            if self.pacer.aborted.is_set():  # stopped while waiting for the block's slot
                raise OutputAborted("the output was stopped; the block was not played")
        out = np.empty((n, K.NOISE_COLS))
        diag = K.empty_diag(n)
        self.sa[:, K.S_SATN] = 0.0
        self._ensure_noise(n)
        K.run_block(*self._kernel_args(), ao, self._noise, self._cursor, out, diag)
        self._cursor += n
        if n:
            self.last_ao[:] = ao[-1]
        self.last_diag = diag
        return out

    def step(self, ao0: float, ao1: float) -> np.ndarray:
        """One sample through the same kernel (the point-by-point path)."""
        self.sa[:, K.S_SATN] = 0.0
        self._ensure_noise(1)
        out = np.empty((1, K.NOISE_COLS))
        ao = self._scratch_ao
        ao[0, 0], ao[0, 1] = ao0, ao1
        K.run_block(*self._kernel_args(), ao, self._noise, self._cursor, out, self._scratch_diag)  # one row
        self._cursor += 1
        self.last_ao[0], self.last_ao[1] = ao0, ao1
        self.last_diag = self._scratch_diag
        return out[0]

    def idle(self) -> int:
        """AO to 0 V, then advance until both amplifier outputs are below 10 mV (cap 20 ms).
        Not paced: a parked output stops the real-time clock."""
        if self.pacer is not None:
            self.pacer.stop_clock()
        max_n = max(int(math.ceil(IDLE_CAP_S * self.sample_rate_hz)), self.latency + 1)
        self._ensure_noise(max_n)
        used = K.run_idle(
            *self._kernel_args(),
            self._noise,
            self._cursor,
            max_n,
            IDLE_THRESHOLD_V,
            self._scratch_out,
            self._scratch_diag,
        )
        self._cursor += used
        self.last_ao[:] = 0.0
        return int(used)

    def applied_ao_v(self) -> np.ndarray:
        """The DAQ volts last written to each amplifier input (Y, Z), whichever path wrote them."""
        if self.latency > 0:
            return self.ring[(int(self.sg[K.SG_RING]) - 1) % self.latency].copy()
        return self.last_ao.copy()

    def amplifier_output_v(self) -> np.ndarray:
        """Each amplifier's output now (Y, Z), actuator volts before output noise."""
        return self.sa[:, K.S_VOUT].copy()

    def closed_loop(self, ref_um: np.ndarray, kp: float, ki: float) -> np.ndarray:
        """Compiled causal point-by-point PI loop on both axes (see kernels.run_closed_loop)."""
        ref = np.ascontiguousarray(ref_um, dtype=np.float64)
        n = ref.shape[0]
        out = np.empty((n, K.NOISE_COLS))
        diag = K.empty_diag(n)
        self._ensure_noise(n)
        um_per_v = np.array([self.config["axes"][ax]["gauge"]["scale_um_per_v"] for ax in AXES], dtype=float)
        gain = self.pa[:, K.A_GAIN].copy()
        rating = np.array([stack_rating_v(self.config, ax) for ax in AXES])
        K.run_closed_loop(
            *self._kernel_args(),
            self._noise,
            self._cursor,
            n,
            ref,
            kp,
            ki,
            um_per_v,
            gain,
            rating[:, 0].copy(),
            rating[:, 1].copy(),
            out,
            diag,
        )
        self._cursor += n
        self.last_diag = diag
        return out

    # ------------------------------------------------------------------ state & faults
    @property
    def time_s(self) -> float:
        return float(self.sg[K.SG_T_S])

    @property
    def temperature_c(self) -> float:
        return float(self.sg[K.SG_TEMP_C])

    def set_temperature_c(self, value_c: float) -> None:
        """Move the ambient base temperature (the drift terms keep running on top)."""
        self.pg[K.G_T0_C] = float(value_c)

    def true_displacement_um(self) -> dict[str, float]:
        return {ax: float(self.sa[a, K.S_XTOOL]) for a, ax in enumerate(AXES)}

    def peak_output_v(self) -> dict[str, float]:
        """Largest |amplifier output| since the last reset_peaks() (noise included)."""
        return {ax: float(self.sa[a, K.S_PEAKV]) for a, ax in enumerate(AXES)}

    def peak_current_a(self) -> dict[str, float]:
        return {ax: float(self.sa[a, K.S_PEAKI]) for a, ax in enumerate(AXES)}

    def reset_peaks(self) -> None:
        self.sa[:, K.S_PEAKV] = 0.0
        self.sa[:, K.S_PEAKI] = 0.0

    def axis_index(self, axis: str) -> int:
        if axis not in AXES:
            raise ValueError(f"unknown axis {axis!r}; the emulator has {', '.join(AXES)}")
        return AXES.index(axis)

    def inject_fault(self, kind: str, axis: str | None = None, at_s: float | None = None) -> None:
        """Fault injection now: "sensor_dropout" (gauge stuck at 0 V, status not ok),
        "sensor_saturation" (the gauge's offset jumps past full scale: it reads +10 V, status saturated)
        or "amplifier_overcurrent" (fault latched, output driven to 0 V). ``axis`` None = both;
        ``at_s`` is the session time to quote in status reasons. Scheduled faults: ``self.faults``."""
        if kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
        for ax in AXES if axis is None else (axis,):
            a = self.axis_index(ax)
            self._injected[kind][ax] = at_s
            if kind == "sensor_dropout":
                self.sa[a, K.S_DROP] = 1.0
            elif kind == "sensor_saturation":
                jump = 2.0 * self.pa[a, K.S_RANGE_UM]
                self._saturation_offset_um[a] += jump
                self.sa[a, K.S_GOFF] += jump
            else:
                self.sa[a, K.S_FAULT] = 1.0
                self.sa[a, K.S_FAULT_I] = max(
                    abs(self.sa[a, K.S_IA]), self.pa[a, K.A_CUR_DV] * self.pa[a, K.A_CAP_F] / self.pg[K.G_DT_S] * 1.25
                )
                self.sa[a, K.S_FAULT_T] = self.pa[a, K.A_FAULT_S]

    def clear_faults(self) -> None:
        """Remove injected faults and clear latched amplifier faults."""
        for a in range(2):
            self.clear_amplifier_fault(a)
            self.sa[a, K.S_DROP] = 0.0
            self.sa[a, K.S_GOFF] -= self._saturation_offset_um[a]
            self.sa[a, K.S_SAT] = 0.0
        self._saturation_offset_um[:] = 0.0
        for kind in self._injected:
            self._injected[kind].clear()

    def clear_amplifier_fault(self, a: int) -> None:
        self.sa[a, K.S_FAULT] = 0.0
        self.sa[a, K.S_OCT] = 0.0
        self.sa[a, K.S_OCQ] = 0.0
        self.sa[a, K.S_OCPEAK] = 0.0
        self._injected["amplifier_overcurrent"].pop(AXES[a], None)

    def injected_note(self, kind: str, axis: str) -> str:
        """ " (injected at t=0.41 s)" for an injected fault, "" otherwise (for status reasons)."""
        if axis not in self._injected.get(kind, ()):
            return ""
        at_s = self._injected[kind][axis]
        return " (injected)" if at_s is None else f" (injected at t={at_s:.2f} s)"

    def kernel_state(self):
        """(world_sample, args) for compiled callers: ``world_sample(*args, ao0, ao1, noise, kn, out, ko, diag)``.
        Callers must supply their own noise rows (use ``take_noise``)."""
        return K.world_sample, self._kernel_args()

    def take_noise(self, n: int) -> tuple[np.ndarray, int]:
        """Reserve n noise rows: returns (array, first row). Keeps the stream reproducible.
        Compiled callers reserve one block (a control period) at a time: that is where a
        real-time world paces them."""
        if self.pacer is not None:
            self.pacer.tick(n, self.sample_rate_hz)
        self._ensure_noise(n)
        start = self._cursor
        self._cursor += n
        return self._noise, start
