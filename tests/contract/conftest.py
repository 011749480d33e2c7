"""The contract tests' slow cases (navlab.contracts.SLOW_REFERENCES) are marked ``slow``; a check
that does not apply (navlab.contracts.ContractSkipped) is a skip.
"""

from __future__ import annotations

import pytest
from contract_data import SLOW_REFERENCES

from navlab.contracts import ContractSkipped


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        params = getattr(getattr(item, "callspec", None), "params", {})
        case = (params.get("fkey"), params.get("scenario"))
        if "reference" in getattr(item, "originalname", "") and case in SLOW_REFERENCES:
            item.add_marker(pytest.mark.slow)


@pytest.hookimpl(wrapper=True)
def pytest_pyfunc_call(pyfuncitem: pytest.Function):
    try:
        return (yield)
    except ContractSkipped as exc:
        pytest.skip(str(exc))
