"""Models: identification and refine requests, a model, a comparison, a diagnosis, a lineage."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from service.http.schemas.common import BENCH_ID_FIELD, OPEN, Label
from service.science.discovery.loop import MAX_STEPS, MAX_STEPS_ALLOWED
from service.usecases.discover_experiments import MAX_EXPERIMENTS


class ModelRequest(BaseModel):
    """Identify a model of one axis from stored datasets."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, protected_namespaces=())

    axis: Literal["y", "z"]
    datasets: list[str] = Field(min_length=1, max_length=100)
    effects: list[str] = Field(default=["hysteresis"])
    model: str = Field(
        default="static_pi",
        description="static_pi | dynamic_pi | grpi | composite | hysterons (the composite on a wider rate-independent base) "
        "(static PI + effects; implied by any effect beyond hysteresis)",
    )
    n_operators: int = Field(default=10, ge=1, le=100)
    name: Label | None = Field(default=None, description="the model's label, as PATCH sets it")


class RefineRequest(BaseModel):
    """Exactly one of: ``add`` an effect, ``remove`` one, or refit with ``effects``."""

    model_config = ConfigDict(extra="forbid")

    add: str | None = None
    remove: str | None = None
    effects: list[str] | None = Field(default=None, max_length=20)
    datasets: list[str] = Field(default=[], max_length=100, description="datasets to add to the fit")


class DiscoverRequest(BaseModel):
    """Run the discovery loop from a model: at most ``max_steps`` model steps (the model's own
    diagnosis is the first; each effect tried counts, kept or not; a refit on an experiment's data
    does not); ``allow_experiments``: run on the bench, when it is free, the sweep the loop needs (an
    ambiguity's separating experiment, or one that makes an effect testable), at most
    ``max_experiments`` of them, each cut to the bench's limits or skipped if it cannot be; without
    it the loop stops at an ambiguity and names the sweep, unless ``continue_past_ambiguity``: then
    it adds the leading claimed effect and goes on (the ambiguity is still named)."""

    model_config = ConfigDict(extra="forbid")

    max_steps: int = Field(default=MAX_STEPS, ge=1, le=MAX_STEPS_ALLOWED)
    allow_experiments: bool = False
    max_experiments: int = Field(default=MAX_EXPERIMENTS, ge=0, le=10)
    continue_past_ambiguity: bool = False


class ModelMetrics(BaseModel):
    """Train and held-out figures (µm): means over blocks, every frequency block counting equally."""

    model_config = OPEN
    train_rms_um: float | None = None
    validation_rms_um: float | None = None
    train_max_abs_um: float | None = None
    validation_max_abs_um: float | None = None
    per_dataset: list[dict[str, Any]] | None = None
    held_out: str | None = Field(default=None, description="what was held out of the fit")
    noise_floor_um: float | None = Field(default=None, description="the data's noise floor, by the diagnosis's rule")
    without_lines: dict[str, Any] | None = Field(
        default=None,
        description="only where the gauge showed lines at rest: train_rms_um and validation_rms_um on the "
        "records with those lines (lines_hz) taken out, the figures the diagnosis and discover give",
    )
    trained_loops_v: list[list[float]] | None = Field(
        default=None,
        description="[min, max] V of the drive over each training stretch of the axis's own "
        "blocks: the loops the model has seen (a trajectory warns beyond them)",
    )


class ModelOrigin(BaseModel):
    """Where the model's data came from: ``bench_id`` is the bench that stored it, this is the stage
    it describes."""

    fitted_on: Literal["this_bench", "imported", "mixed"] = Field(
        description="this_bench: every dataset recorded by a bench of this service; imported: every one "
        "imported from another stage's file (the model describes that stage); mixed: some of each"
    )
    imported: list[dict[str, Any]] = Field(description="the imported datasets: dataset_id, name, filename")


class Model(BaseModel):
    """An identified model: ``parameters`` is ``model.to_dict()``, checked by ``parameters_sha256``."""

    model_config = ConfigDict(protected_namespaces=())
    id: str
    axis: str
    kind: str = Field(description="static_pi | dynamic_pi | grpi | composite | hysterons")
    effects: list[str]
    parent_id: str | None
    datasets: list[str]
    options: dict[str, Any] | None
    parameters: dict[str, Any]
    parameters_sha256: str
    metrics: ModelMetrics
    software_version: str
    job_id: str | None
    created_at: str
    name: str | None = Field(default=None, description="a user's labels (PATCH /api/models/{id})")
    tags: list[str] = []
    notes: str | None = None
    bench_id: str | None = BENCH_ID_FIELD
    origin: ModelOrigin | None = None


class FitFigures(BaseModel):
    model_config = OPEN
    rms_um: float | None = None
    max_abs_um: float | None = None
    fit_pct: float | None = None
    samples: int | None = None


class OverallFigures(FitFigures):
    max_abs_at_s: float | None = Field(
        default=None, description="where the largest |error| falls, s from the record's start"
    )


class ComparisonMetrics(BaseModel):
    model_config = OPEN
    overall: OverallFigures = Field(description="over every sample inside a block")
    train_rms_um: float | None
    validation_rms_um: float | None
    per_block: list[dict[str, Any]] = Field(description="per block: train and validation figures")


class Comparison(BaseModel):
    """Measured vs predicted displacement (µm) and the residual, every ``stride``-th sample (the
    arrays are left out with ``arrays=false``), and the metrics over every sample."""

    model_config = ConfigDict(protected_namespaces=())
    model_id: str
    dataset_id: str
    axis: str
    used_in_fit: bool
    sample_rate_hz: float
    samples: int
    stride: int
    t_s: list[float] | None = None
    u_v: list[float] | None = None
    x_measured_um: list[float] | None = None
    x_predicted_um: list[float] | None = None
    residual_um: list[float] | None = None
    metrics: ComparisonMetrics


class Candidate(BaseModel):
    """A missing effect the residual points to, with the evidence in words."""

    model_config = OPEN
    effect: str
    kind: str | None = Field(default=None, description="physical | capacity")
    score: float | None = Field(
        default=None,
        description=(
            "0..1: the held-out mean square its own test removes (against its reference: the model for "
            "capacity, the model + the flexible base for physics), as a share of this model's held-out mean "
            "square above the noise floor (one denominator, so scores rank as gains do; the candidates: claimed "
            "physics by their size (claim_size_um2: the held-out mean square each removes over its own claim's reference), then the other physics and capacity in score order); the claim is decided by the held-out test, not by the score"
        ),
    )
    score_of: str | None = Field(
        default=None,
        description="the figures the score is the ratio of (nm²): its test's held-out mean-square drop, "
        "levels anchored, over this model's excess above the noise floor; not the RMS figures of its test",
    )
    score_capped: bool = Field(
        default=False, description="the score is 1 because it is capped: its test's drop exceeds this model's excess"
    )
    expected_rms_um: float | None = Field(default=None, description="held-out RMS with the effect added")
    claim_size_um2: float | None = Field(
        default=None,
        description="claimed physics only (µm²): the held-out mean square it removes over its claim's reference "
        "(the model + the flexible base; the model for the loop-shape pair), levels anchored at each block's "
        "training mean: one figure for every claim, the rank's",
    )
    evidence: str | None = None


class Failure(BaseModel):
    """Where the model fails: a place (block, drive range) and its residual."""

    model_config = OPEN
    where: str | None = None
    text: str | None = None
    rms_um: float | None = None


class RemainderSignature(BaseModel):
    signature: str = Field(description='e.g. "gain changing with time", "line at 50 Hz", "response per block"')
    share_of_residual: float = Field(description="the share (0–1) of the unseen rows' residual power it explains")
    share_of_excess: float = Field(description="the share (0–1) of that power above the gauge noise it explains")
    t: float = Field(description="its held-out gain against the gauge noise, in standard errors")
    gain_nm2: float = Field(description="its mean held-out gain in squared error (nm²)")
    text: str = Field(description="what it means, in a physicist's words, with the fitted figure")
    figure: dict[str, Any] = Field(description="x (the signature's variable), residual_nm, x_label: the unseen rows")


class Remainder(BaseModel):
    """The residual a model leaves on the rows it never fitted (held-out cycles, rests, holds), read
    against physical signatures: each fitted on training rows, judged on the unseen rows."""

    unseen_rms_nm: float | None
    unseen_samples: int
    threshold_t: float = Field(description="the Bonferroni-corrected threshold a signature's t must pass")
    tried: list[str]
    signatures: list[RemainderSignature] = Field(description="the significant ones, largest share first (at most 3)")
    shares_overlap: bool = Field(
        default=False, description="the signatures' shares (each fitted alone) sum to more than the whole: they overlap"
    )
    shares_text: str = Field(default="", description="what the shares are of and whether they overlap, in words")


class Answer(BaseModel):
    """The diagnosis's answer, one stored value that the verdict, the Models page's first screen and the
    remainder's section all read."""

    missing: str | None = Field(description="the effect the verdict names (physics), or the capacity to add, or None")
    kind: str | None = Field(description="physical | capacity | None")
    expected_rms_um: float | None = Field(description="the held-out RMS with it added")
    ambiguous_with: str | None = Field(
        default=None, description="the look-alike the data cannot tell ``missing`` from (the diagnosis's ambiguity)"
    )
    remains: str | None = Field(description="the remainder's leading signature (its name), or None")
    remains_share: float | None = Field(description="that signature's share (0–1) of the unseen excess")
    text: str = Field(description="the answer in words, errors in nm")


class DisturbanceLine(BaseModel):
    model_config = OPEN
    frequency_hz: float = Field(description="the line's frequency, refined on its phase across the rests (Hz)")
    amplitude_um: float = Field(description="its amplitude at rest (µm)")
    mains: bool = Field(description="a mains line (50/60 Hz or a harmonic) or another")
    z: float = Field(description="its held-out gain at rest against white noise, in standard errors")
    text: str


class Disturbance(BaseModel):
    """Lines the gauge shows at rest: a disturbance, not the model, taken out of the record before the
    model was judged."""

    model_config = OPEN
    lines: list[DisturbanceLine]
    rest_seconds: float = Field(description="the rests read (s)")
    rest_rms_um: float = Field(description="the RMS at rest with the lines (µm)")
    rest_noise_um: float = Field(description="the RMS at rest without them: the noise floor (µm)")
    removed: bool
    text: str


class Diagnosis(BaseModel):
    """Residual vs noise floor, the verdict, the candidates (claimed physics, the other physics,
    capacity; the claimed by their size, claim_size_um2, the others by score), failures, and the answer the pages show first."""

    model_config = OPEN
    model_id: str | None = None
    axis: str | None = None
    datasets: list[str] | None = None
    effects: list[str] | None = None
    residual_rms_um: float | None = None
    train_rms_um: float | None = None
    noise_floor_um: float | None = None
    verdict: str | None = Field(default=None, description="missing_effect | complete")
    verdict_text: str | None = Field(
        default=None,
        description="the verdict and its tests' figures; what to add next and what remains described are the answer's",
    )
    candidates: list[Candidate] | None = None
    failures: list[Failure] | None = None
    ambiguity: dict[str, Any] | None = None
    experiments_run_here: bool | None = Field(
        default=None,
        description=(
            "false when the model's data were imported (recorded on another stage): the experiments it names "
            "must run there, and allow_experiments is refused"
        ),
    )
    experiments_note: str | None = None
    diagnosed_as: str | None = Field(
        default=None,
        description=(
            "for a paper's model (static/dynamic PI, GRPI): the composite that stands for it in the diagnosis, "
            "and both held-out figures"
        ),
    )
    remainder: Remainder | None = Field(
        default=None,
        description="when the model is not at the noise floor: what remains, described by physical signatures",
    )
    answer: Answer | None = Field(default=None, description="what is missing and what remains, in one value")
    repeated_cycles_rms_um: float | None = Field(
        default=None,
        description="the residual's RMS over the repeated cycles (training and held-out): the whole that "
        "repeatable_rms_um is a part of (never below it)",
    )
    disturbance: Disturbance | None = Field(
        default=None, description="lines on the gauge at rest (mains pickup or another line): not the model"
    )
    not_tried: list[dict[str, str]] | None = Field(
        default=None,
        description="candidates this diagnosis did not fit, each with why ({effect, reason}): a later grid of the "
        "base when an earlier grid already reaches the floor, or the base is not what limits the model",
    )


class HistoryStep(BaseModel):
    model_config = ConfigDict(protected_namespaces=())
    step: int = Field(description="0: the lineage's first model (a discover run's step 0 is the model it starts from)")
    model_id: str
    parent_id: str | None
    effects: list[str]
    change: str | None = Field(description='what changed from the parent: "+creep", "-delay", "refit"')
    datasets: list[str]
    train_rms_um: float | None
    validation_rms_um: float | None
    like_for_like_rms_um: float | None = Field(
        default=None,
        description="held-out RMS (µm) of this step's effects on the last model's datasets (refitted there where "
        "this step was fitted on fewer): every step on the same data",
    )
    original_data_rms_um: float | None = Field(
        default=None,
        description="the like-for-like fit's held-out RMS (µm: this step's effects refitted on the last model's "
        "datasets) on the first model's datasets; not this step's own fit, so it can differ from its held-out RMS",
    )
    created_at: str


class History(BaseModel):
    """The lineage from the first model to this one."""

    model_config = ConfigDict(protected_namespaces=())
    model_id: str
    steps: list[HistoryStep]


class BlockFigure(BaseModel):
    """One block of the report's figures: its name, RMS (µm) and SVG."""

    title: str = Field(description='the block named by what it is: "Y 100 Hz sine (held-out cycle 5)"')
    dataset_id: str
    block_index: int | None
    frequency_hz: float | None
    held_out_rms_um: float | None
    train_rms_um: float | None
    worst: bool = Field(description="the block the diagnosis names worst")
    svg: str = Field(description="the report's figure: the held-out loop (measured, model) and the residual")


class ReportFigures(BaseModel):
    """The model report's figures alone (GET /api/models/{id}/report/figures), for a page to inline."""

    model_config = ConfigDict(protected_namespaces=())
    model_id: str
    axis: str
    noise_floor_um: float | None
    verdict: str | None
    worst_block: int | None = Field(description="index in blocks of the block the diagnosis names worst")
    history_svg: str = Field(
        description="the error history: held-out RMS per lineage step, log scale, the "
        "noise-floor band and the 2× line, each step labelled with its change"
    )
    blocks: list[BlockFigure]
