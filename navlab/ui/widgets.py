"""Experiment configuration widgets, built generically from the registries, bound to the URL.

Every widget that defines a run has a ``key`` and ``bind="query-params"``, so the URL *is* the
configuration: a shared link reproduces the run. Widgets are generated from
:func:`navlab.params.describe` of each class's ``Params``, so filters, scenarios, noise schedules
and outlier models added later appear without touching the pages.

URL / session-state keys (short and stable):

=========================  =============================================
``scn``                    scenario key
``flt``                    filter keys (repeated parameter)
``runs``, ``seed``         Monte Carlo size and base seed
``noise``, ``out``         noise schedule key, outlier model key
``sc.<scenario>.<name>``   a scenario parameter
``ns.<schedule>.<name>``   a noise-schedule parameter
``ol.<model>.<name>``      an outlier-model parameter (``ol.mixture.contamination`` = α)
``fp.<filter>.<name>``     a filter parameter
=========================  =============================================

Only values that differ from their defaults enter the spec (and the URL), so configurations stay
short and new defaults propagate. Every run page starts from the same defaults
(:class:`PageDefaults`), so a link means the same experiment on every page, and the page links
carry the experiment (:func:`spec_query`) from one page to the next. A link value the widgets
cannot take (``runs=-1``, ``flt=unknown``, ``ol.mixture.contamination=5``) is named in a notice
with the reason (:func:`url_problems`) instead of silently falling back to the default.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import streamlit as st

from navlab.errors import NavlabError
from navlab.experiment import (
    KINDS,
    MAX_RUNS,
    SEED_MAX,
    ExperimentSpec,
    Plan,
    as_plan,
    param_groups,
    plan,
    presets,
)
from navlab.filters import registry
from navlab.noise import OUTLIERS, SCHEDULES
from navlab.params import describe
from navlab.scenarios import scenario_registry

SCN, FLT, RUNS, SEED, NOISE, OUT = "scn", "flt", "runs", "seed", "noise", "out"
UI_MAX_RUNS = min(MAX_RUNS, 5000)  # a browser user cannot start more than this per run
BIND = "query-params"
EXTRA_KEY = "_navlab_extra_params"  # uploaded settings that have no widget (kept per session)
CARRY_KEY = "_navlab_carry"  # session: the URL parameters of the last experiment shown
CARRY_SPEC_KEY = "_navlab_carry_spec"  # session: that experiment's spec (JSON), restored on a page change
NOTICE_KEY = "_navlab_url_notice"  # session: {page: (messages, spec json)} — rejected link values
CORE_KEYS = (SCN, FLT, RUNS, SEED, NOISE, OUT)


def pkey(kind: str, owner: str, name: str) -> str:
    """Session-state / URL key of a parameter widget (kind: sc, ns, ol, fp)."""
    return f"{kind}.{owner}.{name}"


# --------------------------------------------------------------------------- defaults


@dataclass(frozen=True)
class PageDefaults:
    """What a page shows before the user (or the URL) changes anything.

    ``filters``/``runs`` None take the scenario's ``default_filters``/``default_runs``.
    """

    scenario: str = "cv2d"
    filters: tuple[str, ...] | None = None
    runs: int | None = None
    seed: int = 1
    # a true R that steps up half-way, without outliers: what an R̂ does is seen at once (the
    # Noise page's preset adds isolated outliers, under which the R̂ of most filters inflate)
    noise_schedule: str = "step"
    outliers: str = "none"


def default_spec(runs: int | None = None) -> ExperimentSpec:
    """The experiment every run page opens on (:class:`PageDefaults`, the scenario's defaults)."""
    d = PageDefaults()
    return ExperimentSpec(
        scenario=d.scenario,
        filters=tuple(default_filters(d.scenario, d)),
        runs=default_runs(d.scenario, d) if runs is None else runs,
        seed=d.seed,
        noise_schedule=d.noise_schedule,
        outliers=d.outliers,
    )


def scenario_keys() -> list[str]:
    """The scenarios the simulation pages offer (not those that need the user's own files:
    those run on the Real data page).
    """
    reg = scenario_registry()
    keys = [k for k, c in reg.items() if not getattr(c, "user_data", False)]
    return sorted(keys, key=lambda k: (k != "cv2d", k))


def filter_keys() -> list[str]:
    return list(registry())


def default_filters(scn: str, defaults: PageDefaults) -> list[str]:
    reg = registry()
    want = defaults.filters
    if want is None:
        want = scenario_registry()[scn].default_filters
    return [k for k in want if k in reg]


def default_runs(scn: str, defaults: PageDefaults) -> int:
    n = defaults.runs if defaults.runs is not None else scenario_registry()[scn].default_runs
    return int(max(1, min(UI_MAX_RUNS, n)))


# --------------------------------------------------------------------------- generic widget


def _float_step(default: float, lo: float | None, hi: float | None) -> float:
    if default:
        return float(10 ** (math.floor(math.log10(abs(default))) - 1))
    if lo is not None and hi is not None and hi > lo:
        return float(10 ** math.floor(math.log10((hi - lo) / 100)))
    return 0.1


def param_widget(
    p: dict[str, Any],
    key: str,
    default: Any,
    container: Any = None,
    *,
    label: str | None = None,
    style: str | None = None,
    step: float | None = None,
) -> Any:
    """One bound widget for a parameter described by :func:`navlab.params.describe`.

    Returns the widget's value, or ``default`` for parameters that have no widget (tuples,
    ``ui=False``). Ranges come from the parameter's ``lo``/``hi``, so impossible values cannot
    be entered. ``label`` replaces the parameter's name; ``style`` "toggle" draws a switch for a
    true/false parameter, "slider" a slider for a number; ``step`` replaces the number's step.
    """
    c = container if container is not None else st
    if not p.get("ui", True) or isinstance(default, tuple):
        return default
    label = label or p["name"].replace("_", " ")
    common = {"key": key, "help": p.get("help") or None, "bind": BIND}
    lo, hi = p.get("lo"), p.get("hi")
    if isinstance(default, bool):
        return (c.toggle if style == "toggle" else c.checkbox)(label, value=default, **common)
    if isinstance(default, int):
        lo_i, hi_i = None if lo is None else math.ceil(lo), None if hi is None else math.floor(hi)
        bounds = {"min_value": lo_i, "max_value": hi_i}
        return int(c.number_input(label, value=int(default), step=step or 1, **bounds, **common))
    if isinstance(default, float):
        lo_f, hi_f = None if lo is None else float(lo), None if hi is None else float(hi)
        step = step or _float_step(default, lo, hi)
        if style == "slider":
            return float(c.slider(label, lo_f, hi_f, float(default), step, **common))
        return float(
            c.number_input(
                label, value=float(default), step=step, format="%g", min_value=lo_f, max_value=hi_f, **common
            )
        )
    choices = p.get("choices")
    if choices:
        opts = list(choices)
        return c.selectbox(label, opts, index=opts.index(default) if default in opts else 0, **common)
    if isinstance(default, str):
        return c.text_input(label, value=default, **common)
    return default


def field_widget(Params: type, name: str, key: str, label: str, *, default: Any = None, **kw: Any) -> Any:
    """A bound widget for field ``name`` of the parameter dataclass ``Params``: its bounds,
    choices and help come from the field's :func:`navlab.params.param` (a page never restates
    them); ``default`` (None: the field's) is the page's starting value. ``kw``: as
    :func:`param_widget` (``container``, ``style``, ``step``).
    """
    p = next(d for d in describe(Params) if d["name"] == name)
    return param_widget(p, key, p["default"] if default is None else default, label=label, **kw)


def param_group(
    kind: str,
    owner: str,
    Params: type,
    container: Any = None,
    overrides: dict[str, Any] | None = None,
    skip: Sequence[str] = (),
) -> dict[str, Any]:
    """Widgets for every parameter of ``Params``; returns only the values that differ from the
    defaults (``overrides`` replaces class defaults, e.g. a scenario's outlier preset).
    """
    out: dict[str, Any] = {}
    for p in describe(Params):
        if p["name"] in skip:
            continue
        default = (overrides or {}).get(p["name"], p["default"])
        if isinstance(default, list):
            default = tuple(default)
        v = param_widget(p, pkey(kind, owner, p["name"]), default, container)
        if v != default:
            out[p["name"]] = v
    return out


def has_widgets(Params: type, skip: Sequence[str] = ()) -> bool:
    return any(
        p.get("ui", True) and not isinstance(p["default"], tuple) and p["name"] not in skip
        for p in describe(Params)
    )


# --------------------------------------------------------------------------- compatibility


@st.cache_data(max_entries=64, show_spinner=False)
def scenario_is_linear(scn: str) -> bool | None:
    """Whether the scenario's nominal model is linear (a 1-run, few-epoch probe; cached).

    A scenario class may declare ``linear = True/False``; otherwise one tiny run is simulated.
    None when unknown (the probe failed).
    """
    cls = scenario_registry()[scn]
    declared = getattr(cls, "linear", None)
    if isinstance(declared, bool):
        return declared
    try:
        from navlab.noise import make_outliers, make_schedule

        names = {p["name"] for p in describe(cls.Params)}
        scen = cls({"epochs": 3} if "epochs" in names else {})
        data = scen.simulate(make_schedule("constant"), make_outliers("none"), [0], 0)
        return bool(getattr(data.model, "linear", True))
    except Exception:  # a probe: any failure means "unknown"
        return None


def filter_problem(fkey: str, scn: str) -> str | None:
    """Why filter ``fkey`` cannot run on scenario ``scn`` (None if it can, as far as known)."""
    fcls = registry()[fkey]
    scls = scenario_registry()[scn]
    if fcls.family == "oracle" and not scls.simulated:
        return "needs simulator ground truth (true R, outlier epochs); this scenario is real data"
    if getattr(fcls, "linear_only", False) and scenario_is_linear(scn) is False:
        return "needs a linear model (uses F and H only); this scenario's model is nonlinear"
    return None


# --------------------------------------------------------------------------- the sidebar


@dataclass
class Config:
    """What :func:`experiment_config` read: the spec (None if invalid) and messages to show."""

    spec: ExperimentSpec | None
    error: str | None = None
    skipped: dict[str, str] = field(default_factory=dict)  # filter key -> reason
    plan: Plan | None = None  # the spec, planned (validated) once: passed on to the run


def _selectbox(c: Any, label: str, options: list[str], default: str, key: str, **kw: Any) -> str:
    idx = options.index(default) if default in options else 0
    return c.selectbox(label, options, index=idx, key=key, bind=BIND, **kw)


def _on_scenario_change(defaults: PageDefaults) -> None:
    """A new scenario starts from its own default filters and runs (unless the page fixes them)."""
    scn = st.session_state.get(SCN)
    if scn not in scenario_registry():
        return
    if defaults.filters is None:
        st.session_state[FLT] = default_filters(scn, defaults)
    if defaults.runs is None:
        st.session_state[RUNS] = default_runs(scn, defaults)
    # parameters some scenario presets (outlier model, filter) restart from the new scenario's
    # value; everything else the user set is kept
    for scls in scenario_registry().values():
        for kind, table in (("ol", scls.outlier_defaults), ("fp", scls.filter_defaults)):
            for owner, values in table.items():
                for name in values:
                    st.session_state.pop(pkey(kind, owner, name), None)


def experiment_config(
    defaults: PageDefaults = PageDefaults(),
    container: Any = None,
    *,
    runs_max: int = UI_MAX_RUNS,
    show_filter_tuning: bool = True,
) -> Config:
    """Render the configuration widgets (in ``container``, default the sidebar) → :class:`Config`.

    Filters that cannot run on the chosen scenario are left out of the spec and reported in
    ``Config.skipped`` with the reason; an invalid combination gives ``Config.error``.
    """
    c = container if container is not None else st.sidebar
    scn = _scenario_select(c, defaults)
    chosen = _filters_select(c, scn, defaults)
    runs, seed = _runs_and_seed(c, scn, defaults, runs_max)
    sparams = _scenario_params(c, scn)
    noise, nparams = _noise_select(c, defaults)
    out, oparams = _outliers_select(c, scn, defaults)
    run_filters, skipped = _runnable(chosen, scn)
    fparams = _filter_tuning(c, scn, run_filters) if show_filter_tuning else {}
    extra = st.session_state.get(EXTRA_KEY) or {}  # uploaded settings that have no widget
    spec_d: dict[str, Any] = {
        "scenario": scn,
        "filters": tuple(run_filters),
        "runs": runs,
        "seed": seed,
        "noise_schedule": noise,
        "noise_params": {**extra.get("noise_params", {}), **nparams},
        "outliers": out,
        "outlier_params": {**extra.get("outlier_params", {}), **oparams},
        "scenario_params": {**extra.get("scenario_params", {}), **sparams},
        "filter_params": fparams,
    }
    return _checked(spec_d, skipped)


def _scenario_select(c: Any, defaults: PageDefaults) -> str:
    """The scenario, with its name and paper below."""
    scn = _selectbox(
        c,
        "Scenario",
        scenario_keys(),
        defaults.scenario,
        SCN,
        help="the simulated experiment (or real recording) every filter runs on",
        on_change=_on_scenario_change,
        args=(defaults,),
    )
    scls = scenario_registry()[scn]
    c.caption(f"**{scls.label}**" + (f" — {scls.paper}" if scls.paper else ""))
    return scn


def _filters_select(c: Any, scn: str, defaults: PageDefaults) -> list[str]:
    """The filters (registry keys), with their names below."""
    reg = registry()
    chosen = c.multiselect(
        "Filters",
        filter_keys(),
        default=default_filters(scn, defaults),
        key=FLT,
        bind=BIND,
        help="registry keys; all selected filters see exactly the same measurements",
    )
    if chosen:
        c.caption(" · ".join(f"`{k}` {reg[k].label}" for k in chosen if k in reg))
    return chosen


def _runs_and_seed(c: Any, scn: str, defaults: PageDefaults, runs_max: int) -> tuple[int, int]:
    """Monte Carlo runs and the seed, side by side."""
    col1, col2 = c.columns(2)
    runs = col1.number_input(
        "Monte Carlo runs",
        min_value=1,
        max_value=int(runs_max),
        value=min(default_runs(scn, defaults), int(runs_max)),
        step=10,
        key=RUNS,
        bind=BIND,
    )
    seed = col2.number_input(
        "Seed", min_value=0, max_value=SEED_MAX, value=defaults.seed, step=1, key=SEED, bind=BIND
    )
    return int(runs), int(seed)


def _scenario_params(c: Any, scn: str) -> dict[str, Any]:
    """The scenario's parameters, in a closed expander (those that differ from the defaults)."""
    scls = scenario_registry()[scn]
    if not has_widgets(scls.Params):
        return {}
    with c.expander("Scenario parameters", expanded=False):
        return param_group("sc", scn, scls.Params)


def _noise_select(c: Any, defaults: PageDefaults) -> tuple[str, dict[str, Any]]:
    """The noise schedule and its parameters (open unless the schedule is constant)."""
    noise = _selectbox(
        c,
        "Noise schedule (true R(t))",
        list(SCHEDULES),
        defaults.noise_schedule,
        NOISE,
        help="how the true measurement-noise σ varies over the run",
    )
    ncls = SCHEDULES[noise]
    c.caption(ncls.summary)
    if not has_widgets(ncls.Params):
        return noise, {}
    with c.expander("Noise-schedule parameters", expanded=noise != "constant"):
        return noise, param_group("ns", noise, ncls.Params)


def _outliers_select(c: Any, scn: str, defaults: PageDefaults) -> tuple[str, dict[str, Any]]:
    """The outlier model and its parameters (the scenario's preset as their defaults)."""
    out = _selectbox(
        c,
        "Outlier model",
        list(OUTLIERS),
        defaults.outliers,
        OUT,
        help="how measurements are contaminated (ground-truth mask recorded)",
    )
    ocls = OUTLIERS[out]
    c.caption(ocls.summary)
    if not has_widgets(ocls.Params):
        return out, {}
    over = presets(scenario_registry()[scn], "ol", out)
    with c.expander("Outlier parameters", expanded=True):
        return out, param_group("ol", out, ocls.Params, overrides=over)


def _runnable(chosen: Sequence[str], scn: str) -> tuple[list[str], dict[str, str]]:
    """The chosen filters that can run on ``scn``, and why each other one cannot."""
    run_filters: list[str] = []
    skipped: dict[str, str] = {}
    for k in (k for k in chosen if k in registry()):
        why = filter_problem(k, scn)
        if why:
            skipped[k] = why
        else:
            run_filters.append(k)
    return run_filters, skipped


def _filter_tuning(c: Any, scn: str, run_filters: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Each filter's parameters in one closed expander (the scenario's presets as defaults)."""
    reg, scls = registry(), scenario_registry()[scn]
    tunable = [k for k in run_filters if has_widgets(reg[k].Params)]
    if not tunable:
        return {}
    fparams: dict[str, dict[str, Any]] = {}
    with c.expander("Filter tuning", expanded=False):
        for k in tunable:
            st.markdown(f"**{reg[k].label}** (`{k}`)")
            vals = param_group("fp", k, reg[k].Params, overrides=presets(scls, "fp", k))
            if vals:
                fparams[k] = vals
    return fparams


def _checked(spec_d: dict[str, Any], skipped: dict[str, str]) -> Config:
    """The spec the widgets read, planned once (or why it cannot run)."""
    try:
        spec = ExperimentSpec.from_dict(spec_d)
        planned = plan(spec) if spec.filters else None
    except NavlabError as exc:
        return Config(None, str(exc), skipped)
    if planned is None:
        msg = "choose at least one filter" if not skipped else "none of the chosen filters can run here"
        return Config(None, msg, skipped)
    return Config(spec, None, skipped, planned)


# --------------------------------------------------------------------------- spec -> widgets


def spec_to_state(spec: ExperimentSpec) -> list[str]:
    """Write ``spec`` into the widgets' session state (call from a callback, before widgets render).

    Returns the settings that have no widget (kept for this session in :data:`EXTRA_KEY`, but not
    in the URL). Raises NavlabError when the spec names something unknown.
    """
    plan(spec)  # validates every key and value first
    ss = st.session_state
    ss[SCN] = spec.scenario
    ss[FLT] = list(spec.filters)
    ss[RUNS] = int(spec.runs)
    ss[SEED] = int(spec.seed)
    ss[NOISE] = spec.noise_schedule
    ss[OUT] = spec.outliers
    extra: dict[str, dict[str, Any]] = {}
    no_widget: list[str] = []
    for g in param_groups(spec):
        section = KINDS[g.kind] + (f".{g.owner}" if g.kind == "fp" else "")
        values = {**g.defaults(), **g.values}
        for d in describe(g.Params):
            name, v = d["name"], values[d["name"]]
            if not d.get("ui", True) or isinstance(d["default"], tuple):
                if name in g.values:
                    extra.setdefault(section, {})[name] = v
                    no_widget.append(f"{section}.{name}")
                continue
            ss[pkey(g.kind, g.owner, name)] = list(v) if isinstance(v, tuple) else v
    ss[EXTRA_KEY] = {k: v for k, v in extra.items() if not k.startswith("filter_params")}
    return no_widget


# --------------------------------------------------------------------------- spec <-> URL


def url_value(v: Any) -> str:
    """A parameter value as the widgets write it into the URL."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _owners(kind: str) -> Mapping[str, Any]:
    return {
        "sc": scenario_registry(),
        "ns": SCHEDULES,
        "ol": OUTLIERS,
        "fp": registry(),
    }[kind]


def _widget_params(cls: Any) -> dict[str, dict[str, Any]]:
    """The parameters of ``cls.Params`` that have a widget, by name."""
    return {
        p["name"]: p
        for p in describe(cls.Params)
        if p.get("ui", True) and not isinstance(p["default"], (tuple, list))
    }


def spec_query(spec: ExperimentSpec | Plan) -> dict[str, str | list[str]]:
    """The URL query of ``spec`` on any run page: the values that differ from the shared defaults
    (the widgets' keys; settings without a widget are not in a URL). Raises NavlabError for a spec
    naming something unknown. ``spec`` may be its plan (then it is not planned again).
    """
    spec = as_plan(spec).spec  # validates every key and value first
    d = PageDefaults()
    q: dict[str, str | list[str]] = {}
    if spec.scenario != d.scenario:
        q[SCN] = spec.scenario
    if list(spec.filters) != default_filters(spec.scenario, d):
        q[FLT] = list(spec.filters)
    if int(spec.runs) != default_runs(spec.scenario, d):
        q[RUNS] = str(int(spec.runs))
    if int(spec.seed) != d.seed:
        q[SEED] = str(int(spec.seed))
    if spec.noise_schedule != d.noise_schedule:
        q[NOISE] = spec.noise_schedule
    if spec.outliers != d.outliers:
        q[OUT] = spec.outliers
    for g in param_groups(spec):
        params, defaults = _widget_params(g.cls), g.defaults()
        for name, v in g.values.items():
            if name in params and v != defaults[name]:
                q[pkey(g.kind, g.owner, name)] = url_value(v)
    return q


def is_experiment_key(key: str) -> bool:
    """Whether URL parameter ``key`` belongs to the experiment (the shared sidebar's widgets)."""
    parts = key.split(".")
    return key in CORE_KEYS or (len(parts) == 3 and parts[0] in ("sc", "ns", "ol", "fp"))


def _check_value(p: dict[str, Any], default: Any, raw: str) -> str | None:
    """Why ``raw`` is not a value the widget of parameter ``p`` takes (None if it is)."""
    lo, hi = p.get("lo"), p.get("hi")
    if isinstance(default, bool):
        return None if raw.lower() in ("true", "false") else "must be true or false"
    if isinstance(default, (int, float)):
        whole = isinstance(default, int)
        try:
            v = float(raw)
        except ValueError:
            v = math.nan
        if not math.isfinite(v) or (whole and v != int(v)):
            return "must be a whole number" if whole else "must be a number"
        lo_w = None if lo is None else (math.ceil(lo) if whole else lo)
        hi_w = None if hi is None else (math.floor(hi) if whole else hi)
        if (lo_w is not None and v < lo_w) or (hi_w is not None and v > hi_w):
            f = "d" if whole else "g"  # a whole number in full (2147483647, not 2.14748e+09)
            rng = (
                f"from {lo_w:{f}} to {hi_w:{f}}"
                if lo_w is not None and hi_w is not None
                else (f"at least {lo_w:{f}}" if lo_w is not None else f"at most {hi_w:{f}}")
            )
            return f"must be {rng}"
        return None
    choices = p.get("choices")
    if choices and raw not in choices:
        return "must be one of " + ", ".join(map(str, choices))
    return None


def url_problems(query: Mapping[str, Sequence[str]], runs_max: int = UI_MAX_RUNS) -> list[str]:
    """Why each experiment value of a link (``{key: [values]}``) is rejected or left unused, one
    message per value naming the parameter; [] when the link is fine. Other pages' own keys are
    not judged here.
    """
    reg, dflt = registry(), PageDefaults()
    options = {
        SCN: (scenario_keys(), "no such scenario"),
        NOISE: (list(SCHEDULES), "no such noise schedule"),
        OUT: (list(OUTLIERS), "no such outlier model"),
    }

    def active(key: str, default: str) -> str:  # the link's value, or the page's fallback for it
        v = (list(query.get(key) or []) or [default])[-1]
        return v if v in options[key][0] else default

    scn = active(SCN, dflt.scenario)
    noise, out = active(NOISE, dflt.noise_schedule), active(OUT, dflt.outliers)
    chosen = list(query.get(FLT) or [])
    msgs: list[str] = []

    def say(key: str, raw: str, why: str) -> None:
        msgs.append(f"`{key}={raw}`: {why}")

    for key, raws in query.items():
        if not is_experiment_key(key):
            continue
        for raw in raws:
            if key in options:
                opts, what = options[key]
                if raw not in opts:
                    say(key, raw, f"{what} (one of: {', '.join(opts)})")
            elif key == FLT:
                if raw not in reg:
                    say(key, raw, "no filter is registered under this key (`python -m navlab list filters`)")
            elif key in (RUNS, SEED):
                hi = runs_max if key == RUNS else SEED_MAX
                why = _check_value({"lo": 1 if key == RUNS else 0, "hi": hi}, 1, raw)
                if why:
                    name = "Monte Carlo runs" if key == RUNS else "the seed"
                    say(key, raw, f"{name} {why}")
            else:
                kind, owner, name = key.split(".")
                owners = _owners(kind)
                noun = {"sc": "scenario", "ns": "noise schedule", "ol": "outlier model", "fp": "filter"}[kind]
                if owner not in owners:
                    say(key, raw, f"no {noun} '{owner}'")
                    continue
                params = _widget_params(owners[owner])
                if name not in params:
                    say(key, raw, f"the {noun} '{owner}' has no parameter '{name}' with a widget")
                    continue
                why = _check_value(params[name], params[name]["default"], raw)
                if why:
                    say(key, raw, f"{name.replace('_', ' ')} {why}")
                    continue
                used = {"sc": scn, "ns": noise, "ol": out}.get(kind)
                if kind == "fp" and owner not in (chosen or default_filters(scn, dflt)):
                    say(key, raw, f"not used: the filter '{owner}' is not among the chosen filters")
                elif used is not None and owner != used:
                    say(key, raw, f"not used: this link's {noun} is '{used}', not '{owner}'")
    return msgs


def link_query() -> dict[str, list[str]]:
    qp = st.query_params
    return {k: qp.get_all(k) for k in qp}


def link_notice(page: str, spec: ExperimentSpec | None, problems: list[str]) -> None:
    """Show the rejected link values (kept on screen, across reruns, until the experiment changes)."""
    notes = st.session_state.setdefault(NOTICE_KEY, {})
    key = None if spec is None else spec.to_json()
    if problems:
        notes[page] = (problems, key)
    msgs, at = notes.get(page, ([], None))
    if not msgs or (at is not None and key is not None and at != key):
        notes.pop(page, None)
        return
    st.warning(
        "Some settings of this link were not used; the page shows its defaults for them:\n"
        + "\n".join(f"- {m}" for m in msgs),
        icon=":material/link_off:",
    )
