"""Markers of the pipeline tests."""


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: starts a `cdgps batch` process and its own cluster (tens of "
                                       "seconds on a loaded machine); deselect with -m 'not slow'")
