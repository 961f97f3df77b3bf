"""The global-optimum net (casest.apps.optimum_net): the stratified 40 of its 320 generated
separable problems, each estimated at casest's defaults, reach the brute-force optimum stored in
scripts/optimum_net_reference.json (the lowest concentrated ML cost of 200 bounded SciPy trf
runs from the priors; `python3 scripts/optimum_net.py --establish`). At the optimum: within
1e-6 log-likelihood units or 1e-9 relative of it, or below it. The whole net:
`python3 scripts/optimum_net.py`."""

import json
import os
import warnings

import pytest

import casest
from casest.apps.optimum_net import NET_SIZE, STRATIFIED, net_problem
from casest.apps.references import at_global_optimum, concentrated_cost

REFERENCE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts",
                         "optimum_net_reference.json")


def _reference() -> dict:
    with open(REFERENCE) as fh:
        return json.load(fh)


def test_every_problem_of_the_net_has_a_reference():
    reference = _reference()
    names = [net_problem(k).name for k in range(NET_SIZE)]
    assert len(set(names)) == NET_SIZE and set(names) <= set(reference)
    # the brute force reaches at least the cost at the truth (the data were simulated from it)
    assert all(reference[n]["J"] <= reference[n]["J_truth"] + 1e-9 * abs(reference[n]["J_truth"]) for n in names)


def test_the_stratified_subset_covers_every_family_noise_and_box():
    names = [net_problem(k).name for k in STRATIFIED]
    assert len(names) >= 40
    assert {n.split("-")[0].rstrip("123") for n in names} == {"exp", "gauss", "rational", "trig"}
    assert {n.split("-")[1] for n in names} == {"n01", "n05", "n20"}
    assert {n.split("-")[2] for n in names} == {"centre", "corner"}


@pytest.mark.parametrize("k", STRATIFIED)
def test_casest_reaches_the_global_optimum(k):
    problem = net_problem(k)
    J_star = _reference()[problem.name]["J"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = casest.estimate(problem.model, problem.data)
    J = concentrated_cost(problem.model, problem.data, est.theta)
    assert at_global_optimum(J, J_star), (problem.name, J, J_star)
