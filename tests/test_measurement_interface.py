"""The measurement interface is declared: casest.problem.Measurement is an abstract base whose
methods both kinds of model implement (a kind that leaves one out cannot be built), and every
stage gets its adapter from measurement_of."""

import inspect

import pytest

import casest
from casest.problem.measurement import DynamicMeasurement, Measurement, StaticMeasurement, measurement_of


def test_the_interface_is_abstract_and_both_kinds_implement_all_of_it():
    declared = Measurement.__abstractmethods__
    assert len(declared) >= 17
    with pytest.raises(TypeError):
        Measurement(None)
    for kind in (StaticMeasurement, DynamicMeasurement):
        assert not inspect.isabstract(kind), kind.__abstractmethods__
        for name in declared:
            assert getattr(kind, name) is not getattr(Measurement, name), (kind.__name__, name)
            assert inspect.getdoc(getattr(kind, name)), (kind.__name__, name)  # documented on the interface


def test_a_kind_without_one_method_cannot_be_built():
    """A new kind with every method of the static one but predict is refused at construction."""
    methods = {name: getattr(StaticMeasurement, name) for name in Measurement.__abstractmethods__ if name != "predict"}
    partial = type("Partial", (Measurement,), methods)
    with pytest.raises(TypeError, match="predict"):
        partial(None)


def test_each_model_kind_gets_its_adapter():
    assert isinstance(measurement_of(casest.load_model_file("scalar2").model()), StaticMeasurement)
    assert isinstance(measurement_of(casest.load_model_file("short_period").model()), DynamicMeasurement)
