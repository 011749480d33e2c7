"""Sharing: configuration JSON download/upload and CSV downloads (streamlit)."""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Sequence
from pathlib import Path

import pandas as pd
import streamlit as st

from navlab.data.loaders import check_offered
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec
from navlab.io import MAX_JSON_BYTES, decode_text
from navlab.ui.frame import presenting
from navlab.ui.uploads import offered_folders
from navlab.ui.widgets import spec_to_state

UPLOAD_MSG_KEY = "_navlab_upload_msg"
log = logging.getLogger(__name__)


def config_download(
    spec: ExperimentSpec, name: str = "navlab-config.json", key: str = "dl_cfg", container=None
) -> None:
    """Download button for the configuration (the same JSON the CLI reads with --config)."""
    c = container if container is not None else st
    c.download_button(
        "Configuration (JSON)",
        spec.to_json(indent=2),
        file_name=name,
        mime="application/json",
        key=key,
        on_click="ignore",
        help="load it back here, or run it with: python -m navlab run --config FILE",
    )


def csv_download(
    df: pd.DataFrame | Callable[[], pd.DataFrame], label: str, name: str, key: str, container=None
) -> None:
    """Download button for a table as CSV (a callable is evaluated only on click); none in
    presentation mode.
    """
    if presenting():
        return
    c = container if container is not None else st
    data = (lambda: df().to_csv(index=False)) if callable(df) else df.to_csv(index=False)
    c.download_button(label, data, file_name=name, mime="text/csv", key=key, on_click="ignore")


def parse_config(
    raw: bytes, name: str = "the uploaded file", offered: Sequence[str | Path] = ()
) -> ExperimentSpec:
    """Uploaded bytes → spec; NavlabError saying what is wrong (not JSON, unknown key, …).

    The bytes go through navlab's one decoding path (:mod:`navlab.io`): BOM removed, binary or
    non-UTF-8 files, oversized or deeply nested JSON refused with a message. A
    ``scenario_params.data_dir`` must lie in the deployment's data root or in one of the
    ``offered`` folders (this session's uploads): the browser cannot name other server folders.
    """
    if not raw.strip():
        raise NavlabError(f"{name} is empty; upload a navlab configuration JSON")
    if len(raw) > MAX_JSON_BYTES:
        raise NavlabError(
            f"{name} is {len(raw) / 1024:.0f} kB, more than the {MAX_JSON_BYTES / 1024:.0f} kB a navlab "
            "configuration may have; upload one downloaded from this page"
        )
    spec = ExperimentSpec.from_json(decode_text(raw, name))
    check_offered(spec.scenario_params.get("data_dir"), offered)
    return spec


def literal(text: str) -> str:
    """``text`` (one line: a message, a table cell) shown as it is by Streamlit's Markdown: the
    characters of links, images, HTML, emphasis, code, LaTeX, tables and entities are escaped, so
    that a file named ``[x](http://host).json`` is a name, not a link; so are the addresses that
    GitHub-flavoured Markdown links by themselves (``www.``, ``://``, ``@``).
    """
    return _AUTOLINK.sub(r"\\\g<0>", _MARKUP.sub(r"\\\g<0>", text))


_MARKUP = re.compile(r"[\\`*_\[\]()<>#!|~$&@]")
_AUTOLINK = re.compile(r"(?i)(?<=www)\.|:(?=//)")


def _on_upload(key: str) -> None:
    f = st.session_state.get(key)
    if f is None:
        return
    try:
        spec = parse_config(f.getvalue(), offered=offered_folders())
        hidden = spec_to_state(spec)
    except NavlabError as exc:
        st.session_state[UPLOAD_MSG_KEY] = ("error", literal(f"Configuration not loaded: {exc}"))
        return
    except Exception as exc:  # never a traceback in the browser: the server log keeps it
        log.exception("configuration upload failed")
        st.session_state[UPLOAD_MSG_KEY] = (
            "error",
            f"Configuration not loaded: it could not be read ({type(exc).__name__}); upload a "
            "configuration downloaded from this page",
        )
        return
    msg = f"Loaded {f.name}: scenario {spec.scenario}, {len(spec.filters)} filters, {spec.runs} runs."
    if hidden:
        msg += " Settings without a widget (kept for this session, not in the URL): " + ", ".join(hidden)
    st.session_state[UPLOAD_MSG_KEY] = ("success", literal(msg))  # the file's name is not Markdown


def config_upload(key: str = "up_cfg", container=None) -> None:
    """Uploader that loads a configuration JSON into the widgets (and so into the URL).

    A broken file leaves the widgets untouched and shows an error saying what is wrong.
    """
    c = container if container is not None else st
    c.file_uploader(
        "Load a configuration (JSON)",
        type=["json"],
        key=key,
        on_change=_on_upload,
        args=(key,),
        help="a file downloaded with 'Configuration (JSON)' or a CLI --config file",
    )
    msg = st.session_state.pop(UPLOAD_MSG_KEY, None)
    if msg:
        kind, text = msg
        (c.error if kind == "error" else c.success)(text)


def text_download(
    make: Callable[[], str],
    label: str,
    name: str,
    key: str,
    mime: str,
    help: str,
    container=None,
) -> None:
    """Download button for generated text (made only when clicked); none in presentation mode."""
    if presenting():
        return
    c = container if container is not None else st
    c.download_button(label, make, file_name=name, mime=mime, key=key, on_click="ignore", help=help)


GO_KEY = "_navlab_go_done"  # session: the specs a ``go=1`` link has already started


def run_on_open(page: str, spec: ExperimentSpec) -> bool:
    """Whether this page was opened by a link asking to run at once (``go=1``, e.g. from Learn or
    the home page's demo): True once per link, then the flag leaves the URL (a reload does not
    run again).
    """
    if str(st.query_params.get("go", "")) != "1":
        return False
    del st.query_params["go"]
    done = st.session_state.setdefault(GO_KEY, set())
    key = (page, spec.to_json())
    if key in done:
        return False
    done.add(key)
    return True
