"""Suite-wide setup: in CI (env ``CI`` set) PyTorch must be present, so parity tests cannot skip;
hypothesis runs derandomized there (the same examples on every run) and with its usual random
exploration elsewhere (``HYPOTHESIS_PROFILE=ci|dev`` chooses)."""

import os

import pytest

try:
    from hypothesis import settings
except ImportError:  # outside CI the property tests skip (helpers.require); in CI they fail to import
    settings = None
if settings is not None:
    settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
    settings.register_profile("dev", print_blob=True)
    settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))


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
