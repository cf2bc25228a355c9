"""trq_offboard/nmpc/cache.py's `loaded_c`, which the flight plan's grid and the RTI's guess
load their hand-written C cores through: the functions typed as asked, and a core whose C reads
another number of items than its Python names refused before anything calls it."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest

from trq_offboard.nmpc.cache import find_compiler, loaded_c

SOURCE = "int n_items(void) { return 3; }\nvoid put(double *x, double v) { x[0] = v; }\n"
PUT = {"put": (ctypes.c_void_p, ctypes.c_double)}


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    if find_compiler() is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("TRQ_CACHE_DIR", str(tmp_path))


def test_a_core_whose_count_agrees_gives_its_functions_typed():
    put, = loaded_c("trq_test_core", SOURCE, (), ("n_items", 3, "items"), PUT)
    x = np.zeros(1)
    put(x.ctypes.data, 2.5)                     # a Python float passed as a C double
    assert x[0] == 2.5 and put.restype is None


def test_a_core_whose_c_reads_another_count_is_refused():
    with pytest.raises(RuntimeError, match="trq_test_core: its C reads 3 items, its Python "
                                           "names 2"):
        loaded_c("trq_test_core", SOURCE, (), ("n_items", 2, "items"), PUT)
