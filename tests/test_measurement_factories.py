"""Every measurement kind is registered in each factory that dispatches on it (stage-1 evaluator,
full-mode NLP, stage-2 solver choice), and an unregistered kind is refused by each, not served a
default. Truth: the subclasses of Measurement that the package defines."""

import pytest

from casest.two_stage.solve.nlps import _full_nlp_of
from casest.two_stage.solve.solver_choice import _solver_of
from casest.two_stage.sweep.orchestration import _evaluator_of
from casest.problem.measurement_base import Measurement

FACTORIES = {"stage-1 evaluator": _evaluator_of, "full-mode NLP": _full_nlp_of, "solver choice": _solver_of}


def _kinds():
    import casest.problem.dynamic_measurement  # noqa: F401  (the kinds register on import)
    import casest.problem.static_measurement  # noqa: F401

    found, todo = [], list(Measurement.__subclasses__())
    while todo:
        kind = todo.pop()
        found.append(kind)
        todo += kind.__subclasses__()
    return found


@pytest.mark.parametrize("factory", list(FACTORIES))
def test_every_measurement_kind_is_registered(factory):
    kinds = _kinds()
    assert len(kinds) >= 2
    registry = FACTORIES[factory].registry
    missing = [k.__name__ for k in kinds if k not in registry]
    assert not missing, f"register {missing} in the {factory} factory"


@pytest.mark.parametrize("factory", list(FACTORIES))
def test_an_unregistered_kind_is_refused(factory):
    class Unknown(Measurement):
        pass

    Unknown.__abstractmethods__ = frozenset()  # a stand-in instance: only its type is dispatched on
    with pytest.raises(TypeError, match="is registered for the measurement kind Unknown"):
        arguments = {"stage-1 evaluator": 4, "full-mode NLP": 3, "solver choice": 2}[factory]
        FACTORIES[factory](object.__new__(Unknown), *[None] * arguments)
