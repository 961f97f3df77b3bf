"""Joint state and parameter estimation by the EKF on the augmented state (summary Sec. 1.2).

Truth: the README pendulum simulated with damping c = 0.3 and process noise on the rate
(Euler-Maruyama, 1 ms steps, fixed seed); the joint filter starts from c = 0.1 with prior
std 0.2 and must end within 3 of its own std of the truth, with that std well below the
prior's; the augmented model's predictions equal the model's at the same values.
"""

import casadi as ca
import numpy as np
import pytest

import casest
from casest.errors import ModelError
from casest.recursive.joint import augmented_model, joint_filter

P = casest.Parameter


def pendulum():
    ang, rate, torque, c, L = (ca.SX.sym(n) for n in ("ang", "rate", "torque", "c", "L"))
    return casest.DynamicModel(
        [P("c", 0.0, 2.0, 0.3), P("L", 0.5, 2.0, 1.0)], [casest.State("ang", 1.0), casest.State("rate", 0.0)],
        ["torque"], rhs={"ang": rate, "rate": -9.81 / L * ca.sin(ang) - c * rate + torque},
        outputs={"px": L * ca.sin(ang), "py": -L * ca.cos(ang)}, substeps=4, input_hold="zoh")


def swing(model, n=600, seed=1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.05
    torque = 0.5 * np.sin(1.3 * t)
    x, truth = np.array([1.0, 0.0]), []
    for k in range(n):
        truth.append(x.copy())
        for _ in range(50):
            acc = -9.81 * np.sin(x[0]) - 0.3 * x[1] + torque[k]
            x = x + 0.001 * np.array([x[1], acc]) + [0.0, np.sqrt(0.05 * 0.001) * rng.standard_normal()]
    truth = np.array(truth)
    bob = np.column_stack([np.sin(truth[:, 0]), -np.cos(truth[:, 0])]) + rng.normal(0, 0.05, (n, 2))
    return model.dataset({"t": t, "torque": torque, "px": bob[:, 0], "py": bob[:, 1]})


def test_the_joint_filter_recovers_the_damping_with_the_states():
    model = pendulum()
    data = swing(model)
    ekf = joint_filter(model, {"c": 0.1, "L": 1.0}, {"c": 0.2**2}, {"rate": 0.05}, [0.05**2, 0.05**2],
                       np.eye(2) * 1e-4)
    assert ekf.model.state_names == ("ang", "rate", "c")
    result = ekf.filter(data)
    c_hat, c_std = result.x_filtered[-1, 2], result.std[-1, 2]
    assert abs(c_hat - 0.3) < 3 * c_std, (c_hat, c_std)
    assert c_std < 0.2 / 4  # the record informed c: its std is a quarter of the prior's or less


def test_the_augmented_model_predicts_as_the_model():
    model = pendulum()
    data = swing(model, n=100)
    joint = augmented_model(model, {"c": 0.3})
    np.testing.assert_allclose(joint.predict_data({"L": 1.0}, data), model.predict_data({"c": 0.3, "L": 1.0}, data),
                               rtol=1e-12, atol=1e-12)
    with pytest.raises(ModelError, match="not parameters"):
        augmented_model(model, {"k": 1.0})
    with pytest.raises(casest.OptionError, match="missing"):
        joint_filter(model, {"c": 0.1}, {"c": 0.04}, {"rate": 0.05}, [0.05**2] * 2, np.eye(2))
