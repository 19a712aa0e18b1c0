"""Suite-wide setup: in CI (env ``CI`` set) PyTorch must be present, so parity tests cannot skip."""

import os

import pytest


def pytest_configure(config):
    if os.environ.get("CI"):
        try:
            import torch  # noqa: F401
        except ImportError as e:  # pragma: no cover - only in a broken CI environment
            raise pytest.UsageError(f"CI is set but torch cannot be imported ({e}): parity tests must run") from e


@pytest.fixture(autouse=True)
def _two_torch_threads():
    """Torch comparisons run with 2 threads, as on the target machine."""
    try:
        import torch
    except ImportError:
        yield
        return
    torch.set_num_threads(2)
    yield
