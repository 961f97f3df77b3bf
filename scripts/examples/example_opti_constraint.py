#!/usr/bin/env python3
"""Embedding example 1: the scalar-2 estimate with a user constraint added through Opti.

    python3 scripts/examples/example_opti_constraint.py [--seed N]

Suppose we know from elsewhere that the offset d equals the amplitude error a (a known
relation between two parameters). casest puts the ML problem into a casadi.Opti; we add
``d == a`` and solve with our own IPOPT settings, then compare with the unconstrained
estimate from casest.estimate.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

import casadi as ca  # noqa: E402

import casest  # noqa: E402
from casest.interop import add_to_opti  # noqa: E402


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    module = casest.load_model_file("scalar2")
    model, data = module.model(), module.simulate(args.seed)

    free = casest.estimate(model, data)

    opti = ca.Opti()
    est = add_to_opti(opti, model, data)
    opti.subject_to(est.parameter("d") == est.parameter("a"))  # the user's own knowledge
    opti.minimize(est.objective)
    est.set_initial(free.theta, free.R)
    opti.solver("ipopt", {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"})
    sol = opti.solve()
    theta, R = est.values(sol)
    cost = casest.ml_cost(model, data, theta, R)

    print(f"{'parameter':>9} {'unconstrained':>14} {'with d = a':>12} {'truth':>8}")
    for i, name in enumerate(model.parameter_names):
        print(f"{name:>9} {free.theta[i]:>14.5f} {theta[i]:>12.5f} {module.TRUTH[name]:>8.3f}")
    print(f"{'R':>9} {free.R[0]:>14.5f} {R[0]:>12.5f}")
    print(f"ML cost: unconstrained {free.cost:.4f}, constrained {cost:.4f} "
          f"(the constraint costs {cost - free.cost:.4f}; a likelihood-ratio statistic of {2 * (cost - free.cost):.3f} "
          "on 1 degree of freedom)")
    return {"free": free.theta, "constrained": theta}


if __name__ == "__main__":
    main()
