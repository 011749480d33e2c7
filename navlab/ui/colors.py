"""One stable colour per filter key, the same on every page and in every chart (pure)."""

from __future__ import annotations

# 20 well-separated colours (Tableau 10 + a darker/lighter complement). The first eight match
# .streamlit/config.toml's chartCategoricalColors.
PALETTE: tuple[str, ...] = (
    "#1f77b4",
    "#d62728",
    "#2ca02c",
    "#9467bd",
    "#ff7f0e",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#bcbd22",
    "#7f7f7f",
    "#393b79",
    "#ad494a",
    "#637939",
    "#7b4173",
    "#e7969c",
    "#6b6ecf",
    "#8ca252",
    "#d6616b",
    "#3182bd",
    "#e6550d",
)
TRUTH_COLOR = "#111111"  # the true R(t), χ² bands and other references

# Pinned colours for the filters the papers compare, so well-known keys never move.
PINNED: dict[str, str] = {
    "kf": "#1f77b4",
    "oracle-kf": "#7f7f7f",
    "chi2-kf": "#d62728",
    "ekf": "#17becf",
    "huber-kf": "#2ca02c",
    "hkf": "#2ca02c",
    "akf": "#9467bd",
    "vb-akf": "#9467bd",
    "hakf": "#ff7f0e",
    "irakf": "#8c564b",
    "vb-ekf": "#e377c2",
    "student-t-kf": "#bcbd22",
}


def filter_colors(keys: list[str] | tuple[str, ...] | None = None) -> dict[str, str]:
    """Colour of every registered filter (plus any extra ``keys``).

    Pinned keys keep their colour; the others take the unused palette colours in sorted-key order,
    so a colour depends only on which filters are registered, never on what a page selected.
    """
    from navlab.filters import registry

    all_keys = sorted(set(registry()) | set(keys or ()))
    out = {k: PINNED[k] for k in all_keys if k in PINNED}
    free = [c for c in PALETTE if c not in set(PINNED.values())]
    rest = [k for k in all_keys if k not in out]
    for i, k in enumerate(rest):
        out[k] = free[i] if i < len(free) else PALETTE[i % len(PALETTE)]
    return out


def filter_color(key: str) -> str:
    """The colour of one filter key."""
    return filter_colors([key])[key]


def rgba(hex_color: str, alpha: float) -> str:
    """``#rrggbb`` → ``rgba(r,g,b,alpha)`` (for translucent spread bands)."""
    h = hex_color.lstrip("#")
    r, g, b = (int(h[i : i + 2], 16) for i in (0, 2, 4))
    return f"rgba({r},{g},{b},{alpha:g})"
