"""Plain numpy pieces for the reference tests of canter's updates, written from the papers rather than from canter's
code: Adam (Kingma & Ba 2015, Algorithm 1) on a flat float64 parameter vector, and an MLP forward pass."""

from __future__ import annotations

import numpy as np


class Adam:
    """Adam on a flat vector: `m`, `v` start at 0, bias-corrected by 1 - beta^t; `lr` may be a vector, one rate
    per parameter."""

    def __init__(self, size: int, lr, eps: float = 1e-8, b1: float = 0.9, b2: float = 0.999):
        self.lr, self.eps, self.b1, self.b2 = lr, eps, b1, b2
        self.m = np.zeros(size)
        self.v = np.zeros(size)
        self.t = 0

    def step(self, theta: np.ndarray, grad: np.ndarray) -> np.ndarray:
        grad = np.asarray(grad, np.float64)
        self.t += 1
        self.m = self.b1 * self.m + (1 - self.b1) * grad
        self.v = self.b2 * self.v + (1 - self.b2) * grad * grad
        m_hat = self.m / (1 - self.b1**self.t)
        v_hat = self.v / (1 - self.b2**self.t)
        return theta - self.lr * m_hat / (np.sqrt(v_hat) + self.eps)


def clip_by_global_norm(grad: np.ndarray, max_norm: float) -> tuple[np.ndarray, float]:
    """(the gradient scaled down to norm `max_norm` if it is longer, its norm before)."""
    norm = float(np.sqrt(np.sum(np.square(grad))))
    return grad * min(1.0, max_norm / norm), norm


ACTIVATIONS = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}


def mlp(layers, x: np.ndarray, activation: str) -> np.ndarray:
    """Dense layers {"w", "b"} with `activation` between them and none after the last, in float64."""
    x = np.asarray(x, np.float64)
    for i, layer in enumerate(layers):
        x = x @ np.asarray(layer["w"], np.float64) + np.asarray(layer["b"], np.float64)
        if i < len(layers) - 1:
            x = ACTIVATIONS[activation](x)
    return x


def gaussian_kl(mean0, log_std0, mean1, log_std1) -> np.ndarray:
    """KL(N(mean0, std0^2) || N(mean1, std1^2)) of diagonal Gaussians, summed over the last axis."""
    return np.sum(
        log_std1 - log_std0 + (np.exp(2 * log_std0) + (mean0 - mean1) ** 2) / (2 * np.exp(2 * log_std1)) - 0.5,
        axis=-1,
    )
