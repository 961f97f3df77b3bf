"""Shared fixtures: the bundled example model files, imported as users import them."""

import os

import pytest

import casest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def model_file(name):
    return casest.load_model_file(os.path.join(REPO, "models", name + ".py"))


@pytest.fixture(scope="session")
def scalar1():
    return model_file("scalar1")


@pytest.fixture(scope="session")
def scalar2():
    return model_file("scalar2")
