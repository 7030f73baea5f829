"""Smooth procedural terrain: a sum of a few long plane waves, scaled to a maximum slope.

The surface is analytic, ``z(x, y) = sum_k A_k sin(k_k . (x, y) + phi_k)``, so the vehicle's height
and tilt come from exact values and gradients, while the ray caster sees the same surface as a grid
mesh (linear between samples; at 2 m spacing and wavelengths over 150 m the two differ by
millimetres). ``max_slope_deg = 0`` gives an exactly flat plane at z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar3d.errors import SimulationError

__all__ = ["Terrain", "TerrainParams", "make_terrain"]


@dataclass(frozen=True, slots=True)
class TerrainParams:
    """How hilly the ground is.

    Attributes:
        max_slope_deg: steepest slope anywhere in the world (0: flat plane).
        min_wavelength_m: shortest undulation.
        max_wavelength_m: longest undulation.
        n_waves: number of superposed plane waves.
        grid_spacing_m: vertex spacing of the terrain mesh.
    """

    max_slope_deg: float = 1.5
    min_wavelength_m: float = 150.0
    max_wavelength_m: float = 420.0
    n_waves: int = 4
    grid_spacing_m: float = 2.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.max_slope_deg < 30.0:
            raise SimulationError(f"terrain max_slope_deg must be in [0, 30), got {self.max_slope_deg}")
        if not 0.0 < self.min_wavelength_m <= self.max_wavelength_m:
            raise SimulationError("terrain wavelengths must satisfy 0 < min_wavelength_m <= max_wavelength_m")
        if self.n_waves < 1 or self.grid_spacing_m <= 0.0:
            raise SimulationError("terrain n_waves must be >= 1 and grid_spacing_m > 0")


@dataclass(frozen=True, slots=True)
class Terrain:
    """An analytic height field over the world's horizontal extent.

    Attributes:
        wave_vectors_rad_per_m: (K, 2) spatial angular frequencies.
        amplitudes_m: (K,) wave amplitudes.
        phases_rad: (K,) wave phases.
        extent_m: (x_min, x_max, y_min, y_max) of the meshed area.
        grid_spacing_m: mesh vertex spacing.
    """

    wave_vectors_rad_per_m: np.ndarray
    amplitudes_m: np.ndarray
    phases_rad: np.ndarray
    extent_m: tuple[float, float, float, float]
    grid_spacing_m: float

    def height_m(self, x_m, y_m) -> np.ndarray:
        """Terrain height at world positions (broadcasting arrays)."""
        x = np.asarray(x_m, float)[..., None]
        y = np.asarray(y_m, float)[..., None]
        k = self.wave_vectors_rad_per_m
        return np.sum(self.amplitudes_m * np.sin(k[:, 0] * x + k[:, 1] * y + self.phases_rad), axis=-1)

    def gradient(self, x_m, y_m) -> np.ndarray:
        """(..., 2) height gradient (dz/dx, dz/dy) at world positions."""
        x = np.asarray(x_m, float)[..., None]
        y = np.asarray(y_m, float)[..., None]
        k = self.wave_vectors_rad_per_m
        c = self.amplitudes_m * np.cos(k[:, 0] * x + k[:, 1] * y + self.phases_rad)
        return np.stack([np.sum(c * k[:, 0], axis=-1), np.sum(c * k[:, 1], axis=-1)], axis=-1)

    def normal(self, x_m, y_m) -> np.ndarray:
        """(..., 3) unit upward surface normal."""
        g = self.gradient(x_m, y_m)
        n = np.concatenate([-g, np.ones(g.shape[:-1] + (1,))], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def grid_axes_m(self) -> tuple[np.ndarray, np.ndarray]:
        """The mesh's x and y vertex coordinates."""
        x0, x1, y0, y1 = self.extent_m
        nx = int(np.ceil((x1 - x0) / self.grid_spacing_m)) + 1
        ny = int(np.ceil((y1 - y0) / self.grid_spacing_m)) + 1
        return x0 + self.grid_spacing_m * np.arange(nx), y0 + self.grid_spacing_m * np.arange(ny)


def make_terrain(
    params: TerrainParams, extent_m: tuple[float, float, float, float], rng: np.random.Generator
) -> Terrain:
    """Draw a terrain whose steepest slope over ``extent_m`` equals ``params.max_slope_deg``."""
    k = params.n_waves
    wavelengths = rng.uniform(params.min_wavelength_m, params.max_wavelength_m, size=k)
    directions = rng.uniform(0.0, np.pi, size=k)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=k)
    weights = rng.uniform(0.5, 1.0, size=k) * wavelengths  # longer waves swing higher
    wave_vectors = (2.0 * np.pi / wavelengths)[:, None] * np.column_stack([np.cos(directions), np.sin(directions)])
    x_min, x_max, y_min, y_max = (float(v) for v in extent_m)
    terrain = Terrain(wave_vectors, weights, phases, (x_min, x_max, y_min, y_max), params.grid_spacing_m)
    if params.max_slope_deg == 0.0:
        return Terrain(wave_vectors, np.zeros(k), phases, terrain.extent_m, params.grid_spacing_m)
    gx, gy = terrain.grid_axes_m()
    xx, yy = np.meshgrid(gx, gy)
    steepest = float(np.max(np.linalg.norm(terrain.gradient(xx, yy), axis=-1)))
    scale = np.tan(np.deg2rad(params.max_slope_deg)) / steepest
    return Terrain(wave_vectors, weights * scale, phases, terrain.extent_m, params.grid_spacing_m)
