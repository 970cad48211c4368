"""The shipped energy-compensation tables are integrals of the compiled GGX model the renderer runs."""

from __future__ import annotations

import numpy as np
import pytest

from monte.core import microfacet as mf


@pytest.mark.parametrize("table, cells", [("ggx_E", [(31, 0), (10, 17), (3, 31)]),
                                          ("glass_E", [(5, 9, 6), (9, 3, 15)]),
                                          ("glass_inv_E", [(9, 9, 6), (5, 3, 15)])])
def test_tables_are_the_compiled_model(table, cells):
    """The generator at the shipped quadrature (128 x 128) integrates the compiled GGX sampler and weights the
    renderer runs (core.bsdf_kernels): shipped cells are reproduced to float32 rounding."""
    n = 32 if table == "ggx_E" else 16
    axis = lambda i: max(i / (n - 1), 1e-4)  # noqa: E731
    for cell in cells:
        *k, j, i = cell  # [z,] mu, rough
        eta = 1.0
        if k:
            z = min(max(k[0] / 15, 1e-4), 0.99)
            eta = (1 + z * z) / (1 - z * z)
            eta = 1 / eta if table == "glass_inv_E" else eta
        got = mf._single_scatter_albedo(np.array([axis(i)]), np.array([axis(j)]), np.array([eta]), 128,
                                        table != "ggx_E")[0]
        assert got == pytest.approx(float(mf.tables()[table][cell]), abs=1e-6), cell
