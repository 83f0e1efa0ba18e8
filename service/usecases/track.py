"""Tracking: an ellipse and its controller checked against the bench, then run and recorded.

The run is ``track_plan`` (service.science.control.session) executed by the bench (in the engine
process by default) and recorded by service.usecases.recorder: measured and reference traces are
chunked to disk period by period and stored as one dataset, partial with its reason when a trip
or a stop ends the run early.
"""

from __future__ import annotations

from dataclasses import asdict

from drivers.bench import Bench
from drivers.interfaces import BenchLost
from service.runtime.jobs import JobContext
from service.science.control.feedforward import SWEEP_FREQUENCIES_HZ, drive_span_v, untrained_turning_points
from service.science.control.gains import choose_pid
from service.science.control.ilc_stability import learning_refusal, mode_spread, predict_plan
from service.science.control.loop import QUEUED_BLOCKS, StopRequested, TrackRecord
from service.science.control.session import (
    PAPER_PID,
    SAMPLE_RATE_HZ,
    Controller,
    plan,
    trace_arrays,
    track_plan,
    trajectory_gains,
)
from service.science.control.trajectory import RAMP_PERIODS, Ellipse, reference
from service.science.control.tuning import TUNED_PID, bench_plants, feedforward_inverts_mode, identified_mode
from service.science.errors import FieldError
from service.science.fitting.validation import trained_loops_v
from service.store import ArrayStoreUnavailable, IntegrityError, NotFoundError, Store
from service.usecases.identify import load_model, load_records
from service.usecases.provenance import foreign_model_warning, model_origin
from service.usecases.recorder import Recorder, Stop, bench_snapshot

#: The path the product recommends to a new user (GET /api/trajectories/recipe; the tracking report walks
#: the same one): the default identification sweep (the paper's four frequencies, 0–120 V, one axis at a
#: time), a composite model per axis on it, then the span sweeps this ellipse needs
#: (POST /api/trajectories/span-sweeps) and the same composite models on those, then FF + PID (auto)
#: + ILC. The effects are what discovery finds on the default bench that a per-axis feedforward can
#: invert, with the loop's delay: rate dependence is left out (its segment-switched terms make the
#: model's output jump, and its inverse is refused), cross-coupling needs the other axis's drive.
FIRST_SWEEP = {"axes": ["y", "z"], "frequencies_hz": [1, 10, 50, 100], "cycles": 5, "together": False}
FEEDFORWARD_EFFECTS = ["hysteresis", "asymmetry", "creep", "delay", "dynamics"]
RECOMMENDED_CONTROLLER = {"pid": "auto", "ilc": True}


def tracking_recipe() -> dict:
    """The recommended path as data, with why, for the dashboard's guided flow and for scripts."""
    return {
        "first_sweep": FIRST_SWEEP,
        "effects": FEEDFORWARD_EFFECTS,
        "controller": RECOMMENDED_CONTROLLER,
        "why": (
            "static PI models leave the flexure's mode, the delay and creep to the PID; composite models with "
            + ", ".join(FEEDFORWARD_EFFECTS[1:])
            + " invert them in the feedforward, and models fitted on the span the ellipse drives know its minor loops"
        ),
    }


def build_controller(
    bench: Bench, store: Store, controller: dict, frequency_hz: float, mode: str = "point_by_point"
) -> Controller:
    """The controller a request describes (``ControllerRequest`` fields as a dict): stored models as
    feedforward per axis, PID gains (chosen and predicted by service.science.control.gains.choose_pid
    on the bench's plant, for a trajectory at ``frequency_hz``), ILC. FieldError names
    ``controller.feedforward_model_<axis>`` when a model is missing or cannot be rebuilt (every model
    inverts itself: service.science.models.contract), ``controller.pid`` when the gains are refused."""
    models = {}
    for ax in ("y", "z"):
        model_id = controller.get(f"feedforward_model_{ax}")
        if model_id is None:
            continue
        field = f"controller.feedforward_model_{ax}"
        try:
            row = store.get_model(model_id)
        except NotFoundError:
            raise FieldError(field, f"no model {model_id!r}") from None
        if row.get("axis") not in (None, ax):
            raise FieldError(
                field,
                f"model {model_id} was identified on the {row['axis'].upper()} axis, not "
                f"{ax.upper()}: its hysteresis and dynamics are the other stack's",
            )
        try:
            models[ax] = load_model(row)
        except Exception as exc:  # a model that cannot be rebuilt or inverted
            raise FieldError(field, f"model {model_id} cannot be used: {exc}") from None
    pid, report, gains = None, None, None
    spec = controller.get("pid")
    plants = bench_plants(bench, models, SAMPLE_RATE_HZ)
    damped = frozenset(
        ax
        for ax, model in models.items()
        if plants.get(ax) is not None and feedforward_inverts_mode(model, plants[ax].resonance_hz)
    )
    if spec is not None:
        if isinstance(spec, dict):
            spec = {ax: (spec[f"kp_{ax}"], spec[f"ki_{ax}"], spec[f"kd_{ax}"], spec["tf_s"]) for ax in ("y", "z")}
        gains, report, warnings = choose_pid(
            spec,
            plants,
            {"tuned": TUNED_PID, "paper": PAPER_PID},
            frequency_hz=frequency_hz,
            force=controller.get("force", False),
            damped_axes=damped,
        )
        report["warnings"] = warnings
        pid = gains
    modes = {ax: identified_mode(model) for ax, model in models.items()}
    ilc_report, harmonics, axis_harmonics = None, controller["ilc_harmonics"], None
    if controller["ilc"]:
        spreads = {ax: plant_spread(plants[ax], modes.get(ax)) for ax in damped}
        ilc_report, axis_harmonics = predict_learning_report(plants, gains, controller, frequency_hz, mode, spreads)
        if len(axis_harmonics) == len(plants):
            harmonics = max(axis_harmonics.values())
    return Controller(
        feedforward=models,
        pid=pid,
        ilc=controller["ilc"],
        ilc_gain=controller["ilc_gain"],
        ilc_harmonics=harmonics,
        ilc_axis_harmonics=axis_harmonics,
        allow_saturation=controller["allow_saturation"],
        pid_report=report,
        ilc_report=ilc_report,
        modes=modes,
        mode_axes=damped,
    )


def predict_learning_report(
    plants: dict, gains: dict | None, controller: dict, frequency_hz: float, mode: str, spreads: dict
) -> tuple[dict, dict]:
    """(the learning's report, axis → the highest harmonic it learns) for the request's ``controller``:
    the convergence predicted over each axis's mode ``spreads`` (ilc_stability.predict_plan).
    FieldError on ``controller.ilc`` when it cannot be predicted."""
    try:
        predicted = predict_plan(
            plants,
            gains,
            controller["ilc_gain"],
            frequency_hz,
            controller["ilc_harmonics"],
            latency_periods=0 if mode == "point_by_point" else QUEUED_BLOCKS - 1,
            spreads=spreads,
        )
    except ValueError as exc:
        raise FieldError("controller.ilc", str(exc)) from None
    axis_harmonics = {p.axis: p.harmonics for p in predicted if p.harmonics >= 0}
    report = {
        "axes": {p.axis: p.as_dict() for p in predicted},
        "spread": {ax: None if sp is None else asdict(sp) for ax, sp in spreads.items()},
        "harmonics": axis_harmonics,
        "refusal": learning_refusal(predicted),
    }
    return report, axis_harmonics


def plant_spread(plant, identified: tuple[float, float] | None):
    """The uncertainty (``ModeSpread``) of an axis's mode: the bench's declared mode and the plant's
    damping (``plant``) beside the feedforward model's identified mode (Hz, ζ)."""
    fns, zetas = [plant.resonance_hz], [plant.damping_ratio]
    if identified is not None:
        fns.append(identified[0])
        zetas.append(identified[1])
    return mode_spread(fns, zetas)


def check_trajectory(bench: Bench, store: Store, ellipse: Ellipse, controller: dict, mode: str) -> Controller:
    """The controller of a tracking request after every check that would refuse it: the reference,
    the feedforward models, the mode, the current, the resonance, the voltage, the stroke
    (``session.plan``) and the ILC's predicted convergence (``controller.ilc_gain`` or
    ``controller.ilc``, service.science.control.ilc_stability; ``force`` runs it anyway). FieldError (a ControlRefused among them) names the field; a failure that
    names none (e.g. a model whose inverse breaks) is laid on ``body``. The returned controller
    carries the planned reference and drive (``planned``) for the run."""
    built = build_controller(bench, store, controller, ellipse.frequency_hz, mode)
    refusal = built.ilc_report and built.ilc_report["refusal"]
    if refusal and not controller.get("force", False):
        raise FieldError(refusal[0], refusal[1] + " (or set controller.force to run it; a diverging run trips to 0 V)")
    warnings: list[str] = []
    try:
        ref, u_ff = plan(bench, ellipse, built, mode, warnings)
    except FieldError:
        raise
    except ValueError as exc:
        raise FieldError("body", str(exc)) from None
    warnings.extend(foreign_models(store, bench, controller))
    if u_ff is not None:
        warnings.extend(extrapolated_loops(store, bench, controller, u_ff[ref.steady]))
        if built.ilc:
            built.trajectory_gain = trajectory_gains(bench, ref, u_ff, built)
    built.planned = (ref, u_ff, warnings)  # the run uses this drive: the engine computes nothing
    return built


def foreign_models(store: Store, bench: Bench, controller: dict) -> list[str]:
    """Warnings for the axes whose feedforward model was fitted on imported data (another stage's)."""
    out = []
    for axis in bench.axes:
        model_id = controller.get(f"feedforward_model_{axis}")
        if model_id is not None:
            why = foreign_model_warning(axis, model_id, model_origin(store, store.get_model(model_id)["datasets"]))
            out += [why] if why else []
    return out


def extrapolated_loops(store: Store, bench: Bench, controller: dict, u_steady_v) -> list[str]:
    """Warnings for the axes whose feedforward model never saw loops near the trajectory's
    (service.science.control.feedforward.untrained_turning_points), from the loops the model row
    records (``metrics.trained_loops_v``). A model stored without them has its datasets read; if they
    cannot be, the warning says the check was not made: the check never stops a run."""
    out = []
    for i, axis in enumerate(bench.axes):
        model_id = controller.get(f"feedforward_model_{axis}")
        if model_id is None:
            continue
        row = store.get_model(model_id)
        loops = row["metrics"].get("trained_loops_v")
        if loops is None:  # identified before models recorded their loops
            try:
                loops = trained_loops_v(load_records(store, row["datasets"], axis))
            except (FieldError, NotFoundError, IntegrityError, ArrayStoreUnavailable) as exc:
                out.append(
                    f"{axis.upper()}: the feedforward model's datasets could not be read ({exc}), so "
                    "whether it was fitted on loops near this trajectory's was not checked"
                )
                continue
        column = u_steady_v[:, i]
        why = untrained_turning_points(loops, axis, (float(column.min()), float(column.max())))
        if why:
            out.append(why)
    return out


def span_sweeps(bench: Bench, store: Store, ellipse: Ellipse, controller: dict) -> list[dict]:
    """Sweep bodies (``POST /api/sweeps``), one per axis, over the voltages the ellipse needs by each
    axis's feedforward model (± ``SPAN_MARGIN_V``, within the bench's limits), at the paper's 1/10/50/100 Hz:
    a model identified on them knows the minor loops the trajectory runs. FieldError names
    ``controller.feedforward_model_<axis>`` when an axis has no model to read the span from."""
    built = build_controller(bench, store, {**controller, "pid": None}, ellipse.frequency_hz)
    ref = reference(ellipse, SAMPLE_RATE_HZ)
    bodies = []
    for i, axis in enumerate(bench.axes):
        model = built.feedforward.get(axis)
        if model is None:
            raise FieldError(
                f"controller.feedforward_model_{axis}",
                "the span is read from the axis's feedforward model: identify one on a default (0–120 V) sweep first",
            )
        lim = bench.limits[axis]
        v_min, v_max = drive_span_v(
            model, ref.x_um[:, i], SAMPLE_RATE_HZ, (lim.v_min_v, lim.v_max_v), steady=ref.steady
        )
        bodies.append(
            {
                "axes": [axis],
                "frequencies_hz": list(SWEEP_FREQUENCIES_HZ),
                "cycles": 5,
                "v_min": round(v_min, 1),
                "v_max": round(v_max, 1),
                "name": f"{axis} span {v_min:.0f}–{v_max:.0f} V for a {ellipse.frequency_hz:g} Hz ellipse",
            }
        )
    return bodies


def run_trajectory(
    ctx: JobContext,
    bench: Bench,
    store: Store,
    ellipse: Ellipse,
    controller: Controller,
    mode: str,
    params: dict,
    name: str | None,
) -> dict:
    """Job body: track, report the error per period as progress, store measured and reference traces;
    returns the metrics (``max_error_y_um``, ``max_error_z_um``, ``rms_error_um``,
    ``relative_error_pct``, ``error_per_period_um``, …) and ``dataset_id``."""
    total = ellipse.cycles + 2 * RAMP_PERIODS  # the steady cycles and both ramps
    meta = {
        "name": name or f"ellipse {ellipse.frequency_hz:g} Hz {mode}",
        "source": "trajectory",
        "axes": list(bench.axes),
        "sample_rate_hz": SAMPLE_RATE_HZ,
        "blocks": [],
        "plan": params,
        "config": bench_snapshot(bench),
    }
    with Recorder(store, meta, ctx) as recorder:

        def on_period(p: int, arrays: dict, last_error_um: float | None) -> None:
            recorder.append(arrays)
            msg = f"period {p + 1}/{total}" + (
                f": error {last_error_um * 1e3:.1f} nm RMS" if last_error_um is not None else ""
            )
            ctx.progress(min(0.97, (p + 1) / total), msg)

        try:
            result, rec, _ = recorder.execute(bench, track_plan, ellipse, controller, mode, on_event=on_period)
        except StopRequested as exc:
            raise recorder.nothing_kept(
                f"{exc.reason} while measuring the response for the ILC; nothing stored", cancelled=True
            ) from None
        except BenchLost as exc:  # the engine died or hung: the periods received are kept
            stop = Stop(str(exc))
            row = recorder.keep_written(stop)
            if row is None:
                raise recorder.nothing_kept(f"{exc}; nothing measured", cancelled=False) from None
            return recorder.end(row, {"dataset_id": row["id"], "samples": row["samples"], "partial": True}, stop)
        stop = tracking_stop(result, rec)
        row = recorder.keep(trace_arrays(rec, SAMPLE_RATE_HZ, bench.axes, 0, rec.samples), stop)
    result["dataset_id"] = row["id"]
    return recorder.end(row, result, stop)


def tracking_stop(result: dict, rec: TrackRecord) -> Stop | None:
    """Why a tracking run ended early: a trip (a fault: the job fails) or a stop on request
    (cancelled); None when it ran every period."""
    if result["tripped"]:
        return Stop(result["tripped"], message=f"tripped: {result['tripped']}")
    if result["stopped"]:
        return Stop(rec.stop_reason, cancelled=True, message=rec.stop_reason or "stopped on request")
    return None
