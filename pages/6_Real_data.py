"""Real data: navlab's filters on a real car drive (INS + GNSS) and real urban pseudoranges."""

import streamlit as st

from navlab.errors import NavlabError
from navlab.filters.base import registry
from navlab.params import MAX_EPOCHS, SEED_MAX
from navlab.scenarios.base import get_scenario_class
from navlab.stats import MIN_RUNS
from navlab.ui import realdata as R
from navlab.ui.frame import frame, plural
from navlab.ui.runner import result_store, show_error
from navlab.ui.uploads import session_uploads, sweep
from navlab.ui.views import chart
from navlab.ui.widgets import BIND, link_notice

frame(
    "Real data",
    "🚗",
    "Real sensors, no simulator: a MEMS IMU in a car aided by 1 Hz GNSS made from its RTK "
    "truth, and GPS/GLONASS pseudoranges from an urban canyon with SPAN ground truth.",
)

sweep()  # upload folders idle for an hour are removed (navlab.ui.uploads)
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
    epochs = st.number_input(
        "Epochs (1 Hz for the drive, 5 Hz for smartLoc; 0 = all)",
        0,
        MAX_EPOCHS,
        120 if is_drive else 300,
        step=10,
        key=f"rd_ep_{scen}",
        bind=BIND,
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
        sp["use_receiver_sigmas"] = st.toggle(
            "R from the receiver's σ (sigma_* columns)", True, key="rd_rxsig", bind=BIND
        )
        sp["sigma_m"] = st.number_input(
            "GNSS σ without receiver σ (m)", 0.01, 100.0, 3.0, key="rd_sigma_own", bind=BIND
        )
        st.caption("Synthetic noise and outliers are off for your own data (options, to stress-test):")
        sp["add_noise"] = st.toggle("Add synthetic noise of that σ", False, key="rd_addnoise", bind=BIND)
        contamination = st.slider("Synthetic outliers α", 0.0, 0.5, 0.0, 0.01, key="rd_alpha_own", bind=BIND)
        scale = st.number_input("Outlier size κ (σ)", 1.0, 100.0, 10.0, key="rd_kappa_own", bind=BIND)
        with st.expander("Geometry and timing"):
            sp["start"] = st.selectbox("Start", ["auto", "static", "moving"], key="rd_start", bind=BIND)
            m1, m2, m3 = st.columns(3)
            sp["mount_roll_deg"] = m1.number_input("IMU roll°", -180.0, 180.0, 0.0, key="rd_mroll", bind=BIND)
            sp["mount_pitch_deg"] = m2.number_input("pitch°", -90.0, 90.0, 0.0, key="rd_mpitch", bind=BIND)
            sp["mount_yaw_deg"] = m3.number_input("yaw°", -180.0, 180.0, 0.0, key="rd_myaw", bind=BIND)
            l1, l2, l3 = st.columns(3)
            sp["lever_right_m"] = l1.number_input(
                "antenna right m", -100.0, 100.0, 0.0, key="rd_lr", bind=BIND
            )
            sp["lever_forward_m"] = l2.number_input("forward m", -100.0, 100.0, 0.0, key="rd_lf", bind=BIND)
            sp["lever_up_m"] = l3.number_input("up m", -100.0, 100.0, 0.0, key="rd_lu", bind=BIND)
            sp["gnss_time_offset_s"] = st.number_input(
                "GNSS time offset (s)", -10.0, 10.0, 0.0, 0.01, key="rd_toff", bind=BIND
            )
            sp["gnss_rate_hz"] = st.number_input(
                "GNSS epochs per second at most (0: as recorded)", 0.0, 100.0, 0.0, key="rd_grate", bind=BIND
            )
    elif is_drive:
        sp["sigma_m"] = st.number_input("GNSS σ (m)", 0.1, 100.0, 3.0, key="rd_sigma", bind=BIND)
        contamination = st.slider("Outlier ratio α", 0.0, 0.5, 0.1, 0.01, key="rd_alpha", bind=BIND)
        scale = st.number_input("Outlier size κ (σ)", 1.0, 100.0, 10.0, key="rd_kappa", bind=BIND)
        o1, o2 = st.columns(2)
        sp["outage_start_s"] = o1.number_input("Outage start (s)", 0.0, 1e4, 0.0, key="rd_out0", bind=BIND)
        sp["outage_len_s"] = o2.number_input("Outage length (s)", 0.0, 1e4, 0.0, key="rd_outlen", bind=BIND)
    else:
        sp["variance_model"] = st.selectbox(
            "Variance model", ["cn0-elevation", "file"], key="rd_varmodel", bind=BIND
        )
        contamination = st.slider(
            "Extra injected outliers α", 0.0, 0.5, 0.0, 0.01, key="rd_alpha_sl", bind=BIND
        )
        scale = st.number_input("Outlier size κ (σ)", 1.0, 100.0, 10.0, key="rd_kappa_sl", bind=BIND)

upload_error = None
if rec == "upload":
    st.markdown(
        "Upload **imu.csv** (`t_s, f_x_mps2, f_y_mps2, f_z_mps2, w_x_radps, w_y_radps, w_z_radps`: "
        "specific force in m/s², rates in rad/s, vehicle axes x right, y forward, z up — or give the "
        "mounting under *Geometry and timing*), **gnss.csv** (`t_s, lat_deg, lon_deg, h_m` ellipsoidal, "
        "optional `sigma_n_m, sigma_e_m, sigma_u_m, vn_mps, ve_mps, vu_mps`) and optionally "
        "**truth.csv** (`t_s, lat_deg, lon_deg, h_m`). Both files on one time base `t_s`; a drive "
        "may start at rest (aligned there) or in motion (initialised from the GNSS). The README "
        "section *Your own drive* says what each column does."
    )
    u1, u2, u3 = st.columns(3)
    f_imu = u1.file_uploader("imu.csv", type=["csv", "txt"], key="rd_up_imu")
    f_gnss = u2.file_uploader("gnss.csv", type=["csv", "txt"], key="rd_up_gnss")
    f_truth = u3.file_uploader("truth.csv (optional)", type=["csv", "txt"], key="rd_up_truth")
    if f_imu is None or f_gnss is None:
        st.info("Upload at least imu.csv and gnss.csv.")
        st.stop()
    try:
        folder = R.save_upload(
            f_imu.getvalue(),
            f_gnss.getvalue(),
            f_truth.getvalue() if f_truth is not None else None,
            uploads=session_uploads(),
        )
    except NavlabError as exc:
        st.error(str(exc))
        st.stop()
    sp["data_dir"] = str(folder)

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
if rec == "upload" and store.get(key) is None:  # plain-words checks before the run
    try:
        R.show_findings(st, R.prerun_findings(spec), expanded=True)
    except NavlabError as exc:
        st.error(str(exc).replace(sp["data_dir"] + "/", "uploaded "))
        st.stop()

c1, c2 = st.columns([1, 5])
run_clicked = c1.button("Run", type="primary", key="rd_run")
c2.caption(
    f"{plural(len(filters), 'filter')} × {plural(runs, 'run')} · scenario `{spec.scenario}` · "
    f"CLI: `python -m navlab run --scenario {spec.scenario} --filters {','.join(filters)}`"
)

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
        if d.scenario == "smartloc-berlin":
            st.caption(
                "Pseudorange channels are whitened by the variance model: R̂ is a variance "
                "multiplier (1 = the model is right)."
            )
    chart(st, R.flags_figure(res, run), "flagged epochs", key="rd_flags", name="flags")
    ft = R.flag_table(res)
    if not ft.empty and ft.shape[1]:
        st.caption("Share of measurement entries per decision (%)")
        st.dataframe(ft.round(2), key="rd_flagtable")

st.markdown("##### Data source and licence")
st.info(R.LICENCES[rec])
