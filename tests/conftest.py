"""Shared fixtures: the bundled example model files, imported as users import them."""

import os
import sys

import pytest

import casest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# the global-optimum nets (package ``nets``) live beside the campaigns that run them, not in the wheel
sys.path.insert(0, os.path.join(REPO, "scripts", "campaigns"))


def model_file(name):
    return casest.load_model_file(os.path.join(REPO, "models", name + ".py"))


@pytest.fixture(scope="session")
def scalar1():
    return model_file("scalar1")


@pytest.fixture(scope="session")
def scalar2():
    return model_file("scalar2")


def pytest_collection_modifyitems(config, items):
    """The tests marked slow last (the AP2 worked example alone takes a minute), so that a run shows
    its progress from its first seconds; the order within each group is kept."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is not None)
