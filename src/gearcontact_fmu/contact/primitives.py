"""Analytic test surfaces for the contact engine (oracles, benchmarks): plain (vertices, faces,
face_points, face_normals) arrays in metres, faces counter-clockwise seen from outside.
"""
from __future__ import annotations

import numpy as np


def _grid_faces(nu: int, nv: int, flip: bool) -> np.ndarray:
    """Two triangles per cell of a (nu+1) x (nv+1) vertex grid (index i*(nv+1)+j)."""
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = (i * (nv + 1) + j).ravel()
    b = a + (nv + 1)
    c = b + 1
    d = a + 1
    if flip:
        f = np.stack([np.c_[a, c, b], np.c_[a, d, c]], axis=1)
    else:
        f = np.stack([np.c_[a, b, c], np.c_[a, c, d]], axis=1)
    return f.reshape(-1, 3).astype(np.int64)


def plate(nx: int, ny: int, size_x: float, size_y: float, z: float = 0.0, up: bool = True,
          centre=(0.0, 0.0)):
    """Flat rectangular surface at height z, outward normal +z (``up``) or -z.
    Returns (vertices, faces)."""
    x = np.linspace(-size_x / 2, size_x / 2, nx + 1) + centre[0]
    y = np.linspace(-size_y / 2, size_y / 2, ny + 1) + centre[1]
    X, Y = np.meshgrid(x, y, indexing="ij")
    V = np.c_[X.ravel(), Y.ravel(), np.full(X.size, float(z))]
    return V, _grid_faces(nx, ny, flip=not up)


def plate_graded(x_edges, y_edges, z: float = 0.0, up: bool = True):
    """Flat surface on a tensor grid with given edge coordinates (refine parts of it)."""
    X, Y = np.meshgrid(np.asarray(x_edges, float), np.asarray(y_edges, float), indexing="ij")
    V = np.c_[X.ravel(), Y.ravel(), np.full(X.size, float(z))]
    return V, _grid_faces(len(x_edges) - 1, len(y_edges) - 1, flip=not up)


def sphere_cap(R: float, half_width: float, n: int, centre=(0.0, 0.0, 0.0), lower: bool = True):
    """Part of a sphere (radius R, centre ``centre``) over the square |x|,|y| <= half_width around
    its lowest (``lower``) or highest point; n x n grid cells. Returns (V, F, face_points,
    face_normals) with the exact surface point (centroid projected radially) and normal."""
    c = np.asarray(centre, float)
    s = np.linspace(-half_width, half_width, n + 1)
    X, Y = np.meshgrid(s, s, indexing="ij")
    Z = np.sqrt(R * R - X * X - Y * Y)
    sgn = -1.0 if lower else 1.0
    V = np.c_[X.ravel(), Y.ravel(), sgn * Z.ravel()] + c
    F = _grid_faces(n, n, flip=lower)
    cen = V[F].mean(axis=1) - c
    nrm = cen / np.linalg.norm(cen, axis=1)[:, None]
    return V, F, c + R * nrm, nrm


def cylinder_patch(R: float, half_width: float, length: float, n_x: int, n_y: int,
                   centre=(0.0, 0.0, 0.0), lower: bool = True):
    """Part of a cylinder (radius R, axis along y through ``centre``) over |x| <= half_width,
    |y - centre_y| <= length/2, around its lowest (``lower``) line. Returns (V, F, fp, fn)."""
    c = np.asarray(centre, float)
    x = np.linspace(-half_width, half_width, n_x + 1)
    y = np.linspace(-length / 2, length / 2, n_y + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    sgn = -1.0 if lower else 1.0
    Z = sgn * np.sqrt(R * R - X * X)
    V = np.c_[X.ravel(), Y.ravel(), Z.ravel()] + c
    F = _grid_faces(n_x, n_y, flip=lower)
    cen = V[F].mean(axis=1) - c
    radial = cen.copy()
    radial[:, 1] = 0.0
    nrm = radial / np.linalg.norm(radial, axis=1)[:, None]
    fp = c + R * nrm
    fp[:, 1] = cen[:, 1] + c[1]
    return V, F, fp, nrm


def cone_band(half_angle: float, rho_in: float, rho_out: float, n_circ: int, n_face: int,
              phi_range=(0.0, 2.0 * np.pi)):
    """Outer surface of a cone with apex at the origin and axis +z (half angle ``half_angle``)
    between cone distances rho_in and rho_out; n_circ cells around, n_face along the generator.
    Returns (V, F, fp, fn) with the exact point/normal at the parameter centroid."""
    closed = np.isclose(phi_range[1] - phi_range[0], 2.0 * np.pi)
    phi = np.linspace(phi_range[0], phi_range[1], n_circ + 1)
    rho = np.linspace(rho_in, rho_out, n_face + 1)
    P, Q = np.meshgrid(phi, rho, indexing="ij")
    sd, cd = np.sin(half_angle), np.cos(half_angle)
    V = np.c_[(Q * sd * np.cos(P)).ravel(), (Q * sd * np.sin(P)).ravel(), (Q * cd).ravel()]
    F = _grid_faces(n_circ, n_face, flip=False)
    if closed:  # merge the seam
        last = n_circ * (n_face + 1)
        F = np.where(F >= last, F - last, F)
        V = V[:last]
    # exact data at the parameter centroid of each triangle: (a,b,c) then (a,c,d) per cell
    pf = np.repeat(np.arange(n_circ), 2 * n_face)
    jf = np.tile(np.repeat(np.arange(n_face), 2), n_circ)
    first = np.tile(np.array([True, False]), n_circ * n_face)
    dphi = (phi_range[1] - phi_range[0]) / n_circ
    drho = (rho_out - rho_in) / n_face
    ph = phi_range[0] + (pf + np.where(first, 2.0 / 3.0, 1.0 / 3.0)) * dphi
    rh = rho_in + (jf + np.where(first, 1.0 / 3.0, 2.0 / 3.0)) * drho
    fp = np.c_[rh * sd * np.cos(ph), rh * sd * np.sin(ph), rh * cd]
    fn = np.c_[cd * np.cos(ph), cd * np.sin(ph), -sd * np.ones_like(ph)]
    return V, F, fp, fn
