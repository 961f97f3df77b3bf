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
