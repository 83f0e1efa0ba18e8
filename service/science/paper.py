"""The seed paper's published figures, in one place: the reports, the tests and the dashboard (through
GET /api/paper) all read them from here, so that a figure is typed once.

Units: µm for displacements and errors, V for voltages, Hz for frequencies, degrees for angles,
µm/V for the static PI's weight sums, PID gains kp V/µm, ki V/(µm·s), kd V·s/µm (as numbers: the control
builds its PIDGains from them, service.science.control.session.PAPER_PID).
"""

from __future__ import annotations

#: Table 6 columns, in the paper's order.
TABLE6_MODELS = ("dynamic_pi", "grpi", "static_pi")
#: Table 6: RMS error (µm) of the three models, {axis: {drive frequency (Hz): (dynamic PI, GRPI, static PI)}}.
TABLE6_RMS_UM = {
    "y": {10.0: (0.0586, 0.0933, 0.0991), 100.0: (0.0812, 0.0985, 0.1075)},
    "z": {10.0: (0.0901, 0.1449, 0.1406), 100.0: (0.1039, 0.1326, 0.1513)},
}
#: §2.3.1: the static PI's RMS error (µm) at 1 Hz.
STATIC_PI_1HZ_RMS_UM = {"y": 0.0881, "z": 0.1432}
#: The static PI's weight sums (µm/V): the stroke per volt of the identified stacks.
STATIC_PI_WEIGHT_SUM_UM_PER_V = {"y": 0.053, "z": 0.077}
#: Strokes (µm) at the 120 V drive, from those weight sums (Fig. 2's loops).
STROKE_AT_120V_UM = {"y": 6.4, "z": 9.3}
#: The FEM's first mode (Hz) per axis: the device as designed.
FEM_FIRST_MODE_HZ = {"y": 482.6, "z": 290.7}
#: The compound controller's PID gains (§3).
PID_GAINS = {"y": {"kp": 50.0, "ki": 300.0, "kd": 0.06}, "z": {"kp": 70.0, "ki": 450.0, "kd": 0.08}}


#: The relative error the paper states for its tracking, one bound for both cases (%).
STATED_RELATIVE_ERROR_BOUND_PCT = 6.2


def _case(name: str, inclination_deg: float, y_range_um: list, z_range_um: list, max_error_um: dict) -> dict:
    """One tracking experiment at 100 Hz: its label, its POST /api/trajectories body, its maximum errors (µm)."""
    (y0, y1), (z0, z1) = y_range_um, z_range_um
    return {
        "label": f"{name} ({inclination_deg:g}°, Y {y0}–{y1} µm, Z {z0}–{z1} µm)",
        "body": {
            "shape": "ellipse",
            "y_range_um": y_range_um,
            "z_range_um": z_range_um,
            "inclination_deg": inclination_deg,
            "frequency_hz": 100,
        },
        "max_error_um": max_error_um,
        # the service's definition (the larger over the axes of max |error| / peak-to-peak), from the
        # paper's own max errors: case 1 6.16 %, case 2 3.85 %; the paper's text states one bound for both
        "relative_error_pct": round(100 * max(max_error_um["y"] / (y1 - y0), max_error_um["z"] / (z1 - z0)), 2),
        "relative_error_below_pct": STATED_RELATIVE_ERROR_BOUND_PCT,
    }


#: The tracking experiments (Fig. 14–15): each as a POST /api/trajectories body (its cycles set by the
#: run), with the measured maximum errors (µm), the relative error they give by the service's definition
#: (%) and the bound the paper states (%).
TRACKING_CASES = {
    "case1": _case("paper case 1", 0, [1, 6], [1, 11], {"y": 0.308, "z": 0.369}),
    "case2": _case("paper case 2", 20, [1, 5], [1, 9], {"y": 0.154, "z": 0.252}),
}


def paper_relative_error(case: str) -> str:
    """A tracking case's relative error as the reports print it (%): by the service's definition from
    the paper's max errors, beside the bound the paper states."""
    c = TRACKING_CASES[case]
    return f"{c['relative_error_pct']:g} (stated < {c['relative_error_below_pct']:g})"


def as_dict() -> dict:
    """Every figure above as JSON-ready data (what GET /api/paper answers)."""
    return {
        "table6_models": list(TABLE6_MODELS),
        "table6_rms_um": {
            axis: [{"frequency_hz": f, **dict(zip(TABLE6_MODELS, cells))} for f, cells in rows.items()]
            for axis, rows in TABLE6_RMS_UM.items()
        },
        "static_pi_1hz_rms_um": STATIC_PI_1HZ_RMS_UM,
        "static_pi_weight_sum_um_per_v": STATIC_PI_WEIGHT_SUM_UM_PER_V,
        "stroke_at_120v_um": STROKE_AT_120V_UM,
        "fem_first_mode_hz": FEM_FIRST_MODE_HZ,
        "pid_gains": {axis: dict(g) for axis, g in PID_GAINS.items()},
        "tracking_cases": TRACKING_CASES,
    }
