"""Every fast (batched) filter equals its plain one-run reference (navlab/filters/reference/).

Parametrised over the registered references × every compatible scenario: the batched filter (with
its shortcuts: closed-form inverses, indexing products, measurement-space iterations, the linear
UT in closed form, the clamp's fast path, …) against the textbook transcription, run by run. The
check is navlab.contracts.check_reference (also run by ``navlab check-filter``).
"""

from __future__ import annotations

import pytest
from contract_data import CASES

from navlab.contracts import check_reference
from navlab.filters.base import FILTERS
from navlab.filters.reference import REFERENCES

REF_CASES = [c for c in CASES if c.values[0] in REFERENCES]


def test_most_filters_have_a_reference():
    # navlab's own filters (an installed plugin's are check-filter's business: it says when one
    # has none)
    missing = sorted(set(FILTERS) - set(FILTERS.plugin_sources) - set(REFERENCES))
    # wls is plain already; the NNMFUKF's network is tested on its own (tests/unit/test_nnmfukf.py);
    # the VB, Sage–Husa and UKF filters' one-run steps are their implementation, compiled and not
    # (tests/unit/test_jit_kernels.py), their numbers pinned (tests/unit/test_linear_pinned.py,
    # test_ukf_pinned.py); the UKF's against FilterPy (tests/unit/test_ukf.py)
    one_run = {"vb-akf", "hakf", "student-t-kf", "sage-husa", "irakf", "rrae", "rakf", "rsshakf"}
    one_run |= {"svd-ukf", "mfukf"}
    assert set(missing) <= {"wls", "nnmfukf", "nnmfukf-guarded", *one_run}, missing


@pytest.mark.parametrize(("fkey", "scenario"), REF_CASES)
def test_fast_filter_equals_its_plain_reference(fkey, scenario):
    check_reference(fkey, scenario)
