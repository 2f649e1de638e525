"""The paper's DNN baseline (Table II): a supervised classifier trained on labelled sensors.

It is not an associator (it needs labels), so it has its own entry point, ``dnn_split``:
the detections of the first ``n_train`` sensors along the road are the labelled training set
("a portion of the data association has already been identified": the upstream sensors), the
detections of the remaining, downstream sensors are the test set. Classes are the true target
ids. (Training on a random subset of sensors instead turns the test into interpolation
between labelled sensors and loses the paper's trend: docs/benchmarks.md.)

Network, as Table II: scikit-learn ``MLPClassifier`` with two hidden layers of 8 neurons,
ReLU activations, the Adam optimiser and a softmax output with cross-entropy loss (what the
paper calls the "Softmax" cost). The paper gives no batch size, learning rate or epoch count:
we use full-batch Adam with learning rate 0.01 for at most 1000 epochs (scikit-learn's
defaults, mini-batches of 200 at 0.001, stop far from convergence within 500 epochs).
Features per detection: p (sensor position), t, v, vt, v^2 t and v t^2, standardised with the
training set's mean and standard deviation.
Train and test accuracy are the core's contract accuracy (``mlkm_core.metrics.accuracy``) of
the predicted classes against the truth.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.neural_network import MLPClassifier
from sklearn.preprocessing import StandardScaler

from mlkm_core.metrics import accuracy
from mlkm_core.types import Dataset

#: Adam epochs (at most; scikit-learn stops earlier when the loss stops improving).
MAX_ITER = 1000
LEARNING_RATE = 0.01


@dataclass(frozen=True)
class DnnResult:
    n_train_sensors: int
    n_test_sensors: int
    train_accuracy: float  # fraction in [0, 1]
    test_accuracy: float


def features(dataset: Dataset) -> np.ndarray:
    """(p, t, v, vt, v^2 t, v t^2) per detection, unscaled."""
    d = dataset.detections
    p = dataset.layout.positions[d.sensor_index]
    t, v = d.stamp, d.velocity
    return np.column_stack([p, t, v, v * t, v * v * t, v * t * t])


def dnn_split(
    dataset: Dataset, n_train: int, seed: int = 0, max_iter: int = MAX_ITER
) -> DnnResult:
    """Train on the first ``n_train`` sensors' labelled detections, test on the others.

    ``seed`` is the network's ``random_state`` (weight initialisation).
    """
    d = dataset.detections
    if d.target is None:
        raise ValueError('the DNN baseline needs ground truth to train on')
    n_sensors = dataset.layout.n_sensors
    if not 1 <= n_train < n_sensors:
        raise ValueError(f'n_train must be in [1, {n_sensors - 1}]')
    train_sensors = np.arange(n_train)
    is_train = np.isin(d.sensor_index, train_sensors) & (d.target >= 0)
    is_test = ~np.isin(d.sensor_index, train_sensors)
    x = features(dataset)
    scaler = StandardScaler().fit(x[is_train])
    net = MLPClassifier(
        hidden_layer_sizes=(8, 8),
        activation='relu',
        solver='adam',
        learning_rate_init=LEARNING_RATE,
        batch_size=int(is_train.sum()),
        max_iter=max_iter,
        random_state=seed,
    )
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', ConvergenceWarning)
        net.fit(scaler.transform(x[is_train]), d.target[is_train])
    pred = net.predict(scaler.transform(x)).astype(np.int64)
    train = accuracy(pred[is_train], d.target[is_train]).accuracy
    test = accuracy(pred[is_test], d.target[is_test]).accuracy
    return DnnResult(n_train, n_sensors - n_train, train, test)
