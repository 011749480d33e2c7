"""The contract tests' slow cases (contract_data.SLOW_REFERENCES) are marked ``slow``."""

from __future__ import annotations

import pytest
from contract_data import SLOW_REFERENCES


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        params = getattr(getattr(item, "callspec", None), "params", {})
        case = (params.get("fkey"), params.get("scenario"))
        if "reference" in getattr(item, "originalname", "") and case in SLOW_REFERENCES:
            item.add_marker(pytest.mark.slow)
