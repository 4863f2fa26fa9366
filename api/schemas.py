"""Request and response bodies: one family per resource, all from two bases.

Inputs forbid unknown keys and non-finite numbers (NaN, ±inf are rejected with 422). Bounds that
depend on the settings (samples, duration, batch size) are checked by the routers and quoted in
the error; the static ones are here.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Discriminator, Field, Tag, create_model, model_validator

from excite.core import bounds
from excite.core.bounds import Range
from excite.motion.vehicle import Limits
from excite.rig.config import all_ranges

RouteFormat = Literal["tum", "kitti", "euroc", "waypoints_csv", "geojson", "control_csv"]
RigName = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_-]{0,63}$",
                               description="Name of a bundled rig (GET /v1/rigs).")]
RouteName = Annotated[str, Field(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")]
SCENE_PATTERN = r"^([0-9a-f]{64}|[a-z][a-z0-9_]{0,63})$"
SceneRef = Annotated[str, Field(pattern=SCENE_PATTERN, description=(
    "The scene the route is scored in: a bundled scene's name (GET /v1/scenes), or the digest of a scene "
    "this key uploaded (POST /v1/scenes). The rig's lidars see its surfaces along the route."))]


def ranged(r: Range, description: str = "", **kw: Any) -> Any:
    """A field in the sane range ``r`` of :mod:`excite.core.bounds`: the schema states the range the
    library enforces (the service may tighten it, never widen it)."""
    text = f"{description} Range {r}.".strip()
    return Field(ge=r.lo, le=r.hi, description=text, **kw)


# Static sanity bounds (excite.core.bounds.ROUTE): beyond them the numbers are not a drive on Earth.
Coord = Annotated[float, ranged(bounds.ROUTE["position_m"])]
Time = Annotated[float, ranged(bounds.ROUTE["t_s"])]
Speed = Annotated[float, ranged(bounds.ROUTE["speed_mps"])]
Quat = Annotated[float, ranged(bounds.ROUTE["quaternion"])]


class In(BaseModel):
    """Base of every request body: unknown keys and NaN/inf are errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class Out(BaseModel):
    """Base of every response body."""

    model_config = ConfigDict(extra="allow")


# --------------------------------------------------------------------------------------------
# Inputs


class TimedPose(In):
    t: Time = Field(description="Time [s].")
    position: list[Coord] = Field(min_length=3, max_length=3, description="Position of V in W [m].")
    quaternion_xyzw: list[Quat] = Field(min_length=4, max_length=4,
                                        description="Orientation of V in W, x-y-z-w, unit norm.")


class StartPose(In):
    x_m: Coord = 0.0
    y_m: Coord = 0.0
    heading_rad: Annotated[float, ranged(bounds.ROUTE["heading_rad"])] = 0.0


class ControlIn(In):
    """Controls at knots, interpolated shape-preserving in between."""

    t_s: list[Time] = Field(min_length=2)
    speed_mps: list[Speed]
    curvature_1pm: list[Annotated[float, ranged(bounds.ROUTE["curvature_1pm"])]]
    grade_rad: list[Annotated[float, ranged(bounds.ROUTE["grade_rad"])]] | None = None
    bank_rad: list[Annotated[float, ranged(bounds.ROUTE["bank_rad"])]] | None = None
    start: StartPose = StartPose()


Waypoint = Annotated[list[Coord], Field(min_length=2, max_length=4)]


class RouteIn(In):
    """A route, given in exactly one way: ``text`` of a route file with its ``format``, JSON
    ``waypoints``, timed ``poses`` or a ``control`` profile."""

    name: RouteName | None = Field(None, description="Route name shown in the report.")
    format: RouteFormat | None = Field(None, description="Format of `text` (required with it).")
    text: str | None = Field(None, description="Contents of a route file.")
    times_text: str | None = Field(None, description="KITTI times file (one time per line).")
    waypoints: list[Waypoint] | None = Field(
        None, min_length=2, description="[x, y(, z)(, speed)] in metres and m/s; all rows alike "
                                        "(3 columns are x, y, z).")
    poses: list[TimedPose] | None = Field(None, min_length=6)
    control: ControlIn | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> "RouteIn":
        given = [k for k in ("text", "waypoints", "poses", "control") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give the route in exactly one of text, waypoints, poses, control "
                             f"(got {', '.join(given) or 'none'})")
        if self.text is not None and self.format is None:
            raise ValueError("format is required with text")
        if self.text is None and self.format is not None:
            raise ValueError("format applies to text only")
        if (self.format == "kitti") != (self.times_text is not None):
            raise ValueError("times_text is required with format kitti and only then")
        return self


# The library's vehicle limits (excite.motion.vehicle.Limits: names and defaults) in their sane ranges
LimitsIn = create_model("LimitsIn", __base__=In, __doc__="Vehicle and test limits. Positive, SI units.",
                        **{f.name: (float, ranged(bounds.LIMITS[f.name], default=f.default)) for f in fields(Limits)})


def parsed_rig(rig: Any) -> Any:
    """A rig as POST /v1/rigs/parse answers it (``{"rig": {…}, "summary": {…}}``) is the rig it
    holds: its response is accepted as it is where a rig is expected (no rig has a ``rig`` key)."""
    if isinstance(rig, dict) and isinstance(rig.get("rig"), dict) and set(rig) <= {"rig", "summary"}:
        return rig["rig"]
    return rig


def _shallow(rig: dict[str, Any]) -> dict[str, Any]:
    # before the rig is handed to a worker: a deep document would exhaust the recursion limit,
    # and a large one costs the worker time before it is refused
    if bounds.nesting(rig) > bounds.MAX_NESTING:
        raise ValueError(f"nested more than {bounds.MAX_NESTING} levels deep (a rig is at most 6)")
    if bounds.size(rig) > bounds.MAX_RIG_NODES:
        raise ValueError(f"more than {bounds.MAX_RIG_NODES} keys and list items (a rig holds a few hundred)")
    return rig


# Tagged, so that a wrong rig is reported against the kind it was (names the tags hide from
# the field names in errors: api.problems.field_name).
RIG_TAGS = ("bundled", "inline")
RigIn = Annotated[Annotated[RigName, Tag("bundled")] |
                  Annotated[dict[str, Any], AfterValidator(parsed_rig), AfterValidator(_shallow), Tag("inline")],
                  Discriminator(lambda rig: "inline" if isinstance(rig, dict) else "bundled")]
RIG_DESCRIPTION = ("A bundled rig's name, or a rig config object (the YAML's structure; the IMU block inline; "
                   f"POST /v1/rigs/parse's response as it is; at most {bounds.MAX_SENSORS} sensors, nested at most "
                   f"{bounds.MAX_NESTING} levels). Sane ranges: " + "; ".join(f"{k} {r}" for k, r in all_ranges().items())
                   + "; targets and priors by unit: " + "; ".join(f"{u} {r}" for u, r in bounds.QUANTITY.items()) + ".")


_LOOP = {"name": "loop", "waypoints": [[0, 0], [30, 0], [30, 20], [0, 20], [0, 1]]}


class RouteScoring(In):
    """What scoring one route needs (the base of the score and plot requests)."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"route": _LOOP, "rig": "robotaxi"},
        {"route": {"control": {"t_s": [0, 10, 20], "speed_mps": [0, 5, 0],
                               "curvature_1pm": [0, 0.1, 0]}}, "segments": 2}]})

    route: RouteIn
    rig: RigIn = Field("robotaxi", description=RIG_DESCRIPTION)
    segments: int = Field(0, ge=0, le=100, description="Report this many route segments' information.")
    limits: LimitsIn | None = Field(None, description="Limits that shape waypoint routes without speeds.")
    scene: SceneRef | None = None


class ScoreRequest(RouteScoring):
    track_points: int = Field(0, ge=0, le=5000,
                              description="Also return the route's path in the world frame at this "
                                          "many equally spaced times (for drawing it; 0: none).")


class PlotRequest(RouteScoring):
    parameter: str | None = Field(None, max_length=100,
                                  description="Colour the route by the information on this parameter "
                                              "(default: on the route's weakest mode).")


class RigYaml(In):
    yaml: str = Field(max_length=200_000, description="The text of a rig YAML file (IMU block inline).")


class BatchRequest(In):
    model_config = ConfigDict(json_schema_extra={"examples": [{"routes": [_LOOP]}]})

    routes: list[RouteIn] = Field(min_length=1)
    rig: RigIn = Field("robotaxi", description=RIG_DESCRIPTION)
    segments: int = Field(0, ge=0, le=100)
    limits: LimitsIn | None = None
    scene: SceneRef | None = None


class Origin(In):
    lon_deg: Annotated[float, Field(ge=-180, le=180)]
    lat_deg: Annotated[float, Field(ge=-85, le=85)]


class ManeuverRequest(In):
    """What to plan: a drive within the lot and the limits that maximises the score."""

    rig: RigIn = Field("robotaxi", description=RIG_DESCRIPTION)
    name: RouteName = "maneuver"
    duration_s: float = ranged(bounds.OPTIMIZE["duration_s"], "Length of the maneuver.", default=90.0)
    lot_x_m: float = ranged(bounds.OPTIMIZE["lot_x_m"], "Lot extent along world x.", default=80.0)
    lot_y_m: float = ranged(bounds.OPTIMIZE["lot_y_m"], "Lot extent along world y.", default=50.0)
    limits: LimitsIn = LimitsIn()
    seed: int = ranged(bounds.OPTIMIZE["seed"], default=0)
    time_budget_s: float = ranged(bounds.OPTIMIZE["time_budget_s"], "Optimizer wall-time budget.",
                                  default=60.0)
    closed: bool = Field(False, description="End where it started.")
    n_random: int = ranged(bounds.OPTIMIZE["n_random"], "Random candidates compared.", default=200)
    origin: Origin | None = Field(None, description="Lot origin in WGS84, for GeoJSON downloads.")
    lot: dict[str, Any] | None = Field(None, description=(
        "The lot as GeoJSON (replaces lot_x_m/lot_y_m): one Polygon (lon/lat, or local metres with "
        "properties.crs = \"local\"; further rings are keep-out zones), optionally an entry Point "
        "(role \"entry\", heading_deg) and ramp/bank/bump Polygons (see excite.plan.site)."))
    criterion: Literal["E", "D", "A"] = Field("E", description=(
        "What to maximise: E (λ_min, the score), D (log det), A (−trace of the inverse)."))
    drivable: bool = Field(False, description=(
        "Plan what a person drives from cones and a sheet (figure-eights, circles, slaloms, straight runs "
        "placed in the lot), chosen by the 10th percentile of its score over the driver model's drives; the "
        "job's links then include the sheet (PDF, PNG), the cone layout (GeoJSON) and the plan (JSON). "
        "criterion, closed and n_random do not apply."))
    speed_max_mps: float | None = Field(None, gt=0, le=100, description=(
        "Drivable plans: the fastest speed the instructions may ask for (at most the lot's safe speed: the "
        "fastest a car reaches and stops from again along the lot's longest straight)."))
    draws: int = Field(30, ge=5, le=200, description="Drivable plans: drives of the driver model per plan "
                                                     "in the robust choice.")
    scene: SceneRef | None = Field(None, description=(
        "Drivable plans: plan in this scene (in the lot's frame; a bundled scene's name or the digest of one "
        "uploaded with POST /v1/scenes): every drive the search scores is seen by the rig's lidars in it. "
        "The free-form optimizer plans scene-blind."))


# --------------------------------------------------------------------------------------------
# Outputs


class FieldError(Out):
    field: str
    message: str


class Problem(Out):
    """RFC 9457 problem details."""

    type: str
    title: str
    status: int
    detail: str
    instance: str
    errors: list[FieldError] | None = None


class Column(Out):
    index: int
    name: str
    unit: str
    target: float


class ParameterOut(Out):
    name: str
    unit: str
    sigma: float | None
    target: float
    ok: bool
    sigma_with_prior: float | None = None


class WeakModeOut(Out):
    eigenvalue_scaled: float
    status: Literal["unobservable", "weak", "ok"]
    sigma_in_targets: float | None
    coordinates: list[tuple[str, float]]
    advice: str


class SegmentOut(Out):
    t_start_s: float
    t_end_s: float
    score: float
    weakest_mode_information: float
    parameter_information: dict[str, float]


class SceneNamed(Out):
    name: str = Field(description="The scene's file name or bundled name.")
    digest: str = Field(description="SHA-256 of the scene's geometry and surfaces.")


class SceneSummary(Out):
    """A scene as read: its digest (what requests name it by), file name, triangles and surfaces."""

    digest: str
    name: str
    triangles: int
    surfaces: int
    surfaces_by_kind: dict[str, int]
    area_m2_by_kind: dict[str, float]
    bounds_m: dict[str, list[float]] = Field(description="min and max corners [x, y, z].")
    size_bytes: int | None = Field(None, description="The stored file's size (uploaded scenes).")
    created_at: float | None = None
    used_at: float | None = None


class SceneOutline(Out):
    surfaces: list[dict[str, Any]] = Field(description=(
        "Per surface: kind, name, segments [[x0, y0, x1, y1], …] seen from above, boxed (its bounding "
        "rectangle instead: too many segments)."))
    bounds_m: list[list[float]]
    boxed: int
    omitted: int


class SceneView(SceneSummary):
    outline: SceneOutline


class SceneList(Out):
    bundled: list[str] = Field(description="The bundled scenes' names.")
    uploaded: list[SceneSummary] = Field(description="This key's scenes, most recently used first.")


class Report(Out):
    """The evaluator's report (excite.score.evaluate.Report.to_dict)."""

    version: int
    route: str
    rig: str
    score: float
    passed: bool
    duration_s: float
    length_m: float
    n_keyframes: int
    rank: int
    nullity: int
    rank_threshold: float
    rank_normalisation: str
    condition_number: float | None
    spectrum_scaled: list[float]
    spectrum_unscaled: list[float]
    spectrum_normalised: list[float]
    column_map: list[Column]
    parameters: list[ParameterOut]
    weak_modes: list[WeakModeOut]
    segments: list[SegmentOut]
    warnings: list[str] = Field(default_factory=list, description=(
        "What about the drive the model does not describe (motion no road vehicle makes: a pose jump, the "
        "wrong axes, not a car), and fewer segments than asked (the drive holds fewer)."))
    score_with_priors: float | None
    timings_ms: dict[str, float]
    scene: SceneNamed | None = Field(None, description="The scene the route was scored in (null: none).")


class Track(Out):
    """The route's path in the frame its poses were given in (a scene's frame; x east/forward,
    y left), at equally spaced times."""

    t_s: list[float]
    x_m: list[float]
    y_m: list[float]


class SceneReading(Out):
    """What the scene leaves undetermined at one scan ray-cast along the route (world-aligned axes)."""

    t_s: float
    x_m: float
    y_m: float
    status: Literal["clear", "weak", "degenerate", "blind"] = Field(description=(
        "clear: every direction determined; weak: some direction's σ from one scan above a lidar "
        "odometry's drift per scan pair (2 cm, 0.05°); degenerate: some direction without information; "
        "blind: nothing in range."))
    unobservable: list[str] = Field(description="The directions without information, in words.")
    weak: list[str] = Field(description="The weak directions, in words.")
    weakest_sigma_in_reference: float | None = Field(description=(
        "σ along the weakest direction with information, in units of the drift per scan pair."))


class ScoreResponse(Report):
    """The report, and the route's path when the request asked for ``track_points`` (in a scene,
    with what the scene leaves undetermined along it)."""

    track: Track | None = None
    scene_track: list[SceneReading] | None = None


class BatchItem(Out):
    index: int
    name: str | None
    report: Report | None
    error: Problem | None


class BatchSummary(Out):
    count: int
    passed: int
    failed: int
    errors: int = Field(description="Routes that could not be scored.")
    min_score: float | None


class BatchResponse(Out):
    summary: BatchSummary
    results: list[BatchItem]


class RigsResponse(Out):
    rigs: list[dict[str, Any]]


class RigParsed(Out):
    rig: dict[str, Any] = Field(description="The rig config object, to send as `rig` in other requests.")
    summary: dict[str, Any] = Field(description="The rig as GET /v1/rigs lists it.")


JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class JobProgress(Out):
    iteration: int | None = None
    score: float | None = None
    constraint_violation: float | None = None
    elapsed_s: float | None = None
    phase: str | None = None


class JobResult(Out):
    """The optimizer's result (excite.plan.OptimizeResult.to_dict); the maneuver itself is
    in the job's download links."""

    report: Report
    comparison: list[dict[str, Any]]
    status: str
    iterations: int
    elapsed_s: float
    cancelled: bool
    score: float
    model_score: float | None
    timings_s: dict[str, float]
    message: str
    ipopt_status: str = ""
    source: str = "optimized"
    criterion: str = "E"
    starts: int = Field(1, description="IPOPT starts that ran.")
    starts_converged: int = Field(0, description="Of them, how many converged.")
    compiled: bool = Field(False, description="Whether the optimizer's model ran compiled (else CasADi's "
                                              "virtual machine: several times slower; the message says why).")
    lot: dict[str, Any] | None = Field(None, description=(
        "The lot planned in, in local metres: polygon and holes ([x, y] rings), entry [x, y, heading] "
        "or null, terrain [{role, polygon}], margin_m."))
    drivable: dict[str, Any] | None = Field(None, description=(
        "A drivable plan's job: plan (plan.json), instructions (one line per element), robust (the score's "
        "10th percentile over the driver model's drives), cones (the cone layout as GeoJSON, in the lot's "
        "metres), candidates (the plans it was chosen among)."))


class Job(Out):
    id: str
    kind: str
    status: JobStatus
    cancel_requested: bool
    created_at: float
    started_at: float | None
    finished_at: float | None
    attempts: int
    progress: JobProgress | None
    result: JobResult | None
    error: Problem | None
    links: dict[str, str]


class Health(Out):
    status: str
    detail: dict[str, Any] = {}
