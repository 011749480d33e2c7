"""Real data: navlab's filters on a real car drive (INS + GNSS) and real urban pseudoranges."""

import streamlit as st

from navlab.diagnostics import FLAG_KINDS, explain
from navlab.errors import NavlabError
from navlab.filters.base import registry
from navlab.noise import OUTLIERS
from navlab.params import SEED_MAX
from navlab.scenarios.base import get_scenario_class
from navlab.stats import MIN_RUNS
from navlab.ui import realdata as R
from navlab.ui.frame import frame, plural, warm_run_once
from navlab.ui.runner import result_store, show_error
from navlab.ui.uploads import session_uploads, sweep
from navlab.ui.views import chart
from navlab.ui.widgets import BIND, field_widget, link_notice

frame(
    "Real data",
    "🚗",
    "Real sensors, no simulator: a MEMS IMU in a car aided by 1 Hz GNSS made from its RTK "
    "truth, GPS/GLONASS pseudoranges from an urban canyon with SPAN ground truth, or your own "
    "drive or pseudoranges (choose an upload under Recording).",
)

sweep()  # upload folders idle for an hour are removed (navlab.ui.uploads)
warm_run_once(R.warm_spec().to_json())  # the drive's kernels compile while the page is read
problems = R.link_problems({k: st.query_params.get_all(k) for k in st.query_params})

with st.sidebar:  # every setting is bound to the URL: a shared link reproduces the run
    st.header("Recording")
    # plain keys as options (no format_func): the URL then holds the key, not the label
    rec = st.selectbox("Recording", list(R.RECORDINGS), key="rd_rec", bind=BIND)
    st.caption(R.RECORDINGS[rec])
    scen = R.scenario_of(rec)
    options = R.usable_filters(scen)
    defaults = [k for k in get_scenario_class(scen).default_filters if k in options]
    filters = st.multiselect("Filters", options, default=defaults, key=f"rd_flt_{scen}", bind=BIND)
    st.caption(" · ".join(f"`{k}` {registry()[k].label}" for k in filters))
    is_drive = scen == "drive0708"
    # every parameter widget takes its bounds, choices and help from the scenario's Params (or
    # the mixture outlier model's, with the scenario's preset as default): none is restated here
    P, mixture = get_scenario_class(scen).Params, OUTLIERS["mixture"].Params
    odef = R.outlier_defaults(scen)

    def outlier_widgets(tag: str, label: str) -> tuple[float, float]:
        """The injected outliers' ratio α and size κ."""
        alpha = field_widget(
            mixture,
            "contamination",
            f"rd_alpha{tag}",
            label,
            default=odef["contamination"],
            style="slider",
            step=0.01,
        )
        return alpha, field_widget(
            mixture, "scale", f"rd_kappa{tag}", "Outlier size κ (σ)", default=odef["scale"]
        )

    epochs = field_widget(
        P, "epochs", f"rd_ep_{scen}", R.epochs_label(rec), default=R.epochs_default(rec), step=10
    )
    runs = st.number_input(
        "Noise/outlier injections (runs)",
        1,
        R.MAX_INJECTIONS,
        1,
        key=f"rd_runs_{scen}",
        bind=BIND,
        help="each run adds an independent draw of noise and outliers to the same real measurements",
    )
    seed = st.number_input("Seed", 0, SEED_MAX, 1, key="rd_seed", bind=BIND)
    sp = {}
    if rec == "upload":  # your own drive: the data as recorded; synthetic noise/outliers are options
        sp["use_receiver_sigmas"] = field_widget(
            P, "use_receiver_sigmas", "rd_rxsig", "R from the receiver's σ (sigma_* columns)", style="toggle"
        )
        sp["sigma_m"] = field_widget(P, "sigma_m", "rd_sigma_own", "GNSS σ without receiver σ (m)")
        st.caption("Synthetic noise and outliers are off for your own data (options, to stress-test):")
        sp["add_noise"] = field_widget(
            P, "add_noise", "rd_addnoise", "Add synthetic noise of that σ", style="toggle"
        )
        contamination, scale = outlier_widgets("_own", "Synthetic outliers α")
        with st.expander("Geometry and timing"):
            sp["start"] = field_widget(P, "start", "rd_start", "Start")
            m1, m2, m3 = st.columns(3, vertical_alignment="bottom")
            sp["mount_roll_deg"] = field_widget(P, "mount_roll_deg", "rd_mroll", "IMU roll°", container=m1)
            sp["mount_pitch_deg"] = field_widget(P, "mount_pitch_deg", "rd_mpitch", "pitch°", container=m2)
            sp["mount_yaw_deg"] = field_widget(P, "mount_yaw_deg", "rd_myaw", "yaw°", container=m3)
            l1, l2, l3 = st.columns(3, vertical_alignment="bottom")
            sp["lever_right_m"] = field_widget(P, "lever_right_m", "rd_lr", "antenna right m", container=l1)
            sp["lever_forward_m"] = field_widget(P, "lever_forward_m", "rd_lf", "forward m", container=l2)
            sp["lever_up_m"] = field_widget(P, "lever_up_m", "rd_lu", "up m", container=l3)
            sp["gnss_time_offset_s"] = field_widget(
                P, "gnss_time_offset_s", "rd_toff", "GNSS time offset (s)", step=0.01
            )
            sp["gnss_rate_hz"] = field_widget(
                P, "gnss_rate_hz", "rd_grate", "GNSS epochs per second at most (0: as recorded)"
            )
            sp["imu_rate_hz"] = field_widget(P, "imu_rate_hz", "rd_imurate_own", "IMU rate (Hz; 0: raw)")
    elif is_drive:
        sp["sigma_m"] = field_widget(P, "sigma_m", "rd_sigma", "GNSS σ (m)")
        contamination, scale = outlier_widgets("", "Outlier ratio α")
        o1, o2 = st.columns(2, vertical_alignment="bottom")  # a label that wraps keeps the boxes level
        sp["outage_start_s"] = field_widget(
            P, "outage_start_s", "rd_out0", "Outage start (s)", container=o1, step=1.0
        )
        sp["outage_len_s"] = field_widget(
            P, "outage_len_s", "rd_outlen", "Outage length (s)", container=o2, step=1.0
        )
        sp["imu_rate_hz"] = field_widget(P, "imu_rate_hz", "rd_imurate", "IMU rate (Hz; 0: raw)")
    else:  # pseudoranges: smartLoc Berlin or an upload (own keys: its defaults differ)
        tag = "_pr" if rec == "upload-pr" else ""
        sp["variance_model"] = field_widget(P, "variance_model", f"rd_varmodel{tag}", "Variance model")
        sp["height_aiding"] = field_widget(P, "height_aiding", f"rd_height{tag}", "Height aiding")
        if rec == "upload-pr":
            sp["height_m"] = field_widget(P, "height_m", "rd_height_m_pr", "Street height (m, ellipsoidal)")
        contamination, scale = outlier_widgets(tag or "_sl", "Extra injected outliers α")

if rec == "upload":
    sp["data_dir"] = str(
        R.upload_folder(
            st,
            "Upload **imu.csv** (`t_s, f_x_mps2, f_y_mps2, f_z_mps2, w_x_radps, w_y_radps, w_z_radps`: "
            "specific force in m/s², rates in rad/s, vehicle axes x right, y forward, z up — or give the "
            "mounting under *Geometry and timing*), **gnss.csv** (`t_s, lat_deg, lon_deg, h_m` ellipsoidal, "
            "optional `sigma_n_m, sigma_e_m, sigma_u_m, vn_mps, ve_mps, vu_mps`) and optionally "
            "**truth.csv** (`t_s, lat_deg, lon_deg, h_m`). Both files on one time base `t_s`; a drive "
            "may start at rest (aligned there) or in motion (initialised from the GNSS). The docs page "
            "*Data sources* (docs/data.md), section *Your own drive*, says what each column does.",
            (
                ("imu.csv", "rd_up_imu", True),
                ("gnss.csv", "rd_up_gnss", True),
                ("truth.csv", "rd_up_truth", False),
            ),
            R.save_upload,
            session_uploads(),
        )
    )
elif rec == "upload-pr":
    sp["data_dir"] = str(
        R.upload_folder(
            st,
            "Upload **pseudoranges.csv** (`t_s, sat_id, system, pseudorange_m, sat_x_m, sat_y_m, sat_z_m`, "
            "optional `var_m2, elevation_deg, cn0_dbhz`: one row per satellite and epoch, corrected for "
            "the satellite clock and the atmosphere, satellite ECEF at transmit time), optionally "
            "**odometry.csv** (`t_s, speed_mps, yaw_rate_radps`) and **truth.csv** (`t_s, lat_deg, "
            "lon_deg, h_m` or ECEF `x_m, y_m, z_m`). The docs page *Data sources* (docs/data.md), section "
            "*Your own pseudoranges*, says "
            "what each column does; a smartLoc sequence runs from the CLI (`--set scenario.data_dir=`).",
            (
                ("pseudoranges.csv", "rd_up_pr", True),
                ("odometry.csv", "rd_up_odo", False),
                ("truth.csv", "rd_up_prtruth", False),
            ),
            R.save_pr_upload,
            session_uploads(),
        )
    )

if not filters:
    st.warning("Choose at least one filter.")
    st.stop()

spec = R.build_spec(
    rec,
    filters,
    epochs=int(epochs),
    runs=int(runs),
    seed=int(seed),
    contamination=float(contamination),
    outlier_scale=float(scale),
    scenario_params=sp,
)
link_notice("real_data", spec, problems)  # link values not used, named as on the other pages
key = spec.to_json()
store = result_store()
if rec in R.UPLOADS and store.get(key) is None:  # plain-words checks before the run
    try:
        R.show_findings(st, R.prerun_findings(spec), expanded=True)
        st.caption(R.time_estimate(spec))
    except NavlabError as exc:
        st.error(str(exc).replace(sp["data_dir"] + "/", "uploaded "))
        st.stop()

c1, c2 = st.columns([1, 5])
run_clicked = c1.button("Run", type="primary", key="rd_run")
c2.caption(
    f"{plural(len(filters), 'filter')} × {plural(runs, 'run')} · scenario `{spec.scenario}` · the same run:"
)
c2.code(R.cli_line(spec), language="bash", wrap_lines=True)

res = store.get(key)
if run_clicked and res is None:
    bar = st.progress(0.0, text="starting…")
    try:
        res = R.run_with_progress(spec, lambda f, msg: bar.progress(min(f, 1.0), text=msg))
    except NavlabError as exc:
        bar.empty()
        st.error(str(exc))
        st.stop()
    except Exception as exc:  # never a traceback
        bar.empty()
        show_error(exc)
        st.stop()
    bar.empty()
    store.put(key, res)

if res is None:
    st.info("Press **Run** to run the chosen filters on this recording.")
else:
    d = res.data
    run = 0
    if d.B > 1:
        run = st.number_input("Show run", 0, d.B - 1, 0, key="rd_show_run")
    st.subheader("Results")
    R.show_findings(st, R.run_findings(res))
    st.table(R.metrics_table(res))
    st.caption(
        f"{d.K} epochs · {d.B} run(s) · computed in {res.elapsed_s:.1f} s. "
        "Median/90 % horizontal errors pool every epoch and run; [lo, hi]: the 95 % interval over "
        f"the runs (from {MIN_RUNS} runs on; fewer give none)."
    )
    chart(st, R.track_figure(res, run), "track in local east/north metres", key="rd_track", name="track")
    log_y = st.toggle("log scale", False, key="rd_log")
    chart(st, R.error_figure(res, run, log_y), "horizontal error over time", key="rd_err", name="error")
    if any(fr.R_hat is not None for fr in res.runs.values()):
        ch = st.selectbox(
            "Channel (satellite or axis) for R̂",
            list(range(len(d.channel_names))),
            format_func=lambda i: d.channel_names[i],
            key="rd_ch",
        )
        chart(st, R.rhat_figure(res, ch, run), "R-hat per channel", key="rd_rhat", name="rhat")
        if d.scenario in ("smartloc-berlin", "own-pseudoranges"):
            st.caption(
                "Pseudorange channels are whitened by the variance model: R̂ is a variance "
                "multiplier (1 = the model is right)."
            )
    chart(st, R.flags_figure(res, run), "flagged epochs", key="rd_flags", name="flags")
    ft = R.flag_table(res)
    if not ft.empty and ft.shape[1]:
        st.caption("Share of measurement entries per decision (%)")
        st.dataframe(ft.round(2), key="rd_flagtable")
    for e in explain(res, kinds=FLAG_KINDS):  # what a flag share means
        st.info(e.markdown(), icon=":material/lightbulb:")

st.markdown("##### Data source and licence")
st.info(R.LICENCES[rec])
