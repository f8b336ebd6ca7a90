import pytest

from ._common import MEASURED


@pytest.fixture(scope="session", autouse=True)
def _print_measurements():
    """Print the worst measured value of each hard-case quantity (visible with `-s`)."""
    yield
    if MEASURED:
        print("\n\nhard cases: worst measured values")
        for name in sorted(MEASURED):
            print(f"  {name:<70s} {MEASURED[name]:.3e}")
