"""The global-optimum net (nets.optimum_net): 320 generated separable problems with
brute-force references stored in scripts/campaigns/optimum_net_reference.json (the lowest concentrated ML
cost of 200 bounded SciPy trf runs from the priors; `python3 scripts/campaigns/optimum_net.py
--establish`). At the optimum: within 1e-6 log-likelihood units or 1e-9 relative of it, or below.
The default suite runs the stratified 40; the whole net: `python3 scripts/campaigns/optimum_net.py`
(314 of 320 at the optimum and the six MERGING_TERMS answered by their merged limit; 313 at the
optimum on 0d0a90f and 310 on cf71ecf, the others lost in a CAUTION)."""

import json
import os
import warnings

import numpy as np
import pytest

import casest
from nets.optimum_net import KNOWN_LOSSES, MERGING_TERMS, NET_SIZE, STRATIFIED, net_problem
from nets.published_net import KNOWN_PUBLISHED_LOSSES, published_names, published_problem
from nets.references import at_global_optimum, concentrated_cost
from casest.status import NoteCode, TrustCode

REFERENCE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts",
                         "campaigns", "optimum_net_reference.json")


def _reference() -> dict:
    with open(REFERENCE) as fh:
        return json.load(fh)


def test_every_problem_of_the_net_has_a_reference():
    reference = _reference()
    names = [net_problem(k).name for k in range(NET_SIZE)]
    assert len(set(names)) == NET_SIZE and set(names) <= set(reference) and set(KNOWN_LOSSES) <= set(names)
    # the brute force reaches at least the cost at the truth (the data were simulated from it)
    assert all(reference[n]["J"] <= reference[n]["J_truth"] + 1e-9 * abs(reference[n]["J_truth"]) for n in names)


def test_the_merging_losses_have_no_attained_optimum():
    """The reference of each loss in MERGING_TERMS is two exponential terms merging: rates within 10 %
    (or both at the same bound) and amplitudes of opposite sign over 100 times the largest true one,
    the signature of a cost whose infimum lies at no point of the box."""
    reference = _reference()
    names = {net_problem(k).name: k for k in range(NET_SIZE)}
    for name in MERGING_TERMS:
        problem = net_problem(names[name])
        theta = reference[name]["theta"]
        terms = [(theta[f"a{i}"], theta[f"b{i}"]) for i in range(3) if f"b{i}" in theta]
        largest_truth = max(abs(problem.truth[f"a{i}"]) for i in range(len(terms)))
        merging = [(p, q) for i, p in enumerate(terms) for q in terms[i + 1:]
                   if abs(p[1] - q[1]) <= 0.1 * max(p[1], q[1]) and p[0] * q[0] < 0
                   and min(abs(p[0]), abs(q[0])) > 100 * largest_truth]
        assert merging, (name, terms)


def test_the_stratified_subset_covers_every_family_noise_and_box():
    names = [net_problem(k).name for k in STRATIFIED]
    assert len(names) >= 40
    assert {n.split("-")[0].rstrip("123") for n in names} == {"exp", "gauss", "rational", "trig"}
    assert {n.split("-")[1] for n in names} == {"n01", "n05", "n20"}
    assert {n.split("-")[2] for n in names} == {"centre", "corner"}


@pytest.mark.parametrize("k", STRATIFIED)
def test_casest_reaches_the_optimum_or_says_caution(k):
    """At the optimum unless a known loss, and never "trust it" away from it; a problem of
    MERGING_TERMS (no attained minimum) answered by a merged limit at or below the reference, with a
    MERGING note."""
    problem = net_problem(k)
    J_star = _reference()[problem.name]["J"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = casest.estimate(problem.model, problem.data)
    J = concentrated_cost(problem.model, problem.data, est.theta)
    reached = at_global_optimum(J, J_star)
    if problem.name in MERGING_TERMS and not reached:
        limit = est.merged_limit
        assert limit is not None and NoteCode.MERGING in est.note_codes, problem.name
        J_limit = concentrated_cost(limit.limit_model(problem.model), problem.data, limit.theta)
        assert at_global_optimum(J_limit, J_star), (problem.name, J_limit - J_star)
    else:
        assert reached != (problem.name in KNOWN_LOSSES), (problem.name, J - J_star, "update KNOWN_LOSSES with the measurement")
    if not reached:
        assert est.conclusion()[0] is not TrustCode.TRUSTED, (problem.name, J - J_star)


# -- the published part: 27 NIST StRD problems x (start 1, start 2, box midpoint), 81 problems --
PUBLISHED = published_names()


def test_the_published_part_has_every_nist_problem_and_its_certified_optimum_inside_each_box():
    """The certified values (NIST, 128-bit) lie inside every problem's box and give J_star there
    (to 1e-6 relative)."""
    assert len(PUBLISHED) == 81 and set(KNOWN_PUBLISHED_LOSSES) <= set(PUBLISHED)
    for name in PUBLISHED:
        pr = published_problem(name)
        model = pr.model
        assert np.all(pr.certified >= model.lower_bounds) and np.all(pr.certified <= model.upper_bounds), name
        # Lanczos1's certified RSS (1.4e-25) is below what its 11-digit certified values reproduce
        if not name.startswith("Lanczos1/"):
            assert abs(concentrated_cost(model, pr.data, pr.certified) - pr.J_star) < 1e-6 * max(1.0, abs(pr.J_star)), name


@pytest.mark.parametrize("name", PUBLISHED)
def test_casest_reaches_the_certified_optimum_or_says_caution(name):
    """At the certified optimum unless a known loss, and never "trust it" away from it. Bennett5
    from start 1 and from the box midpoint fail here when a multi-start's short budget keeps
    MINPACK's unverified point instead of IPOPT's (its valley then takes IPOPT over 1000
    iterations from MINPACK's point; casest cf71ecf: gaps 0.015 and 0.26, success False)."""
    pr = published_problem(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = casest.estimate(pr.model, pr.data)
    J = concentrated_cost(pr.model, pr.data, est.theta)
    reached = at_global_optimum(J, pr.J_star)
    assert reached != (name in KNOWN_PUBLISHED_LOSSES), (name, J - pr.J_star, "update KNOWN_PUBLISHED_LOSSES")
    if not reached:
        assert est.conclusion()[0] is not TrustCode.TRUSTED, (name, J - pr.J_star)
