"""The direct HPIPM binding (trq_offboard/nmpc/hpipm.py) against a dense KKT solve in NumPy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trq_offboard.nmpc import hpipm

pytestmark = pytest.mark.skipif(not hpipm.available()[0], reason="no libhpipm in casadi")


def _problem(rng, N=4, ns=3, nv=2):
    At = rng.normal(size=(N, ns, ns)) * 0.4
    Bt = rng.normal(size=(N, nv, ns))
    b = rng.normal(size=(N, ns)) * 0.1
    q = rng.normal(size=(N + 1, ns))
    r = rng.normal(size=(N, nv))
    L = rng.normal(size=(ns + nv, ns + nv))
    H = L @ L.T + np.eye(ns + nv)             # stage Hessian of [s; v], with cross terms
    HN = np.eye(ns) * 2.0
    return At, Bt, b, q, r, H, HN


def _dense_kkt(At, Bt, b, q, r, H, HN, fixed_u=None):
    """The same QP in the variables [u_0, x_1, u_1, ..., x_N] by its KKT system (equalities only;
    fixed_u: {(k, i): value} pinned inputs)."""
    N, ns, nv = At.shape[0], At.shape[1], Bt.shape[1]
    iu = [k * (nv + ns) for k in range(N)]                  # u_k at iu[k], x_{k+1} after it
    ix = [None] + [iu[k] + nv for k in range(N)]
    n = N * (nv + ns)
    Hd, g = np.zeros((n, n)), np.zeros(n)
    for k in range(N):
        u = slice(iu[k], iu[k] + nv)
        Hd[u, u] += H[ns:, ns:]
        g[u] += r[k]
        if k > 0:
            x = slice(ix[k], ix[k] + ns)
            Hd[x, x] += H[:ns, :ns]
            Hd[u, x] += H[ns:, :ns]
            Hd[x, u] += H[:ns, ns:]
            g[x] += q[k]
    xN = slice(ix[N], ix[N] + ns)
    Hd[xN, xN] += HN
    g[xN] += q[N]
    rows, rhs = [], []
    for k in range(N):                      # x_{k+1} - A_k x_k - B_k u_k = b_k
        E = np.zeros((ns, n))
        E[:, ix[k + 1]:ix[k + 1] + ns] = np.eye(ns)
        E[:, iu[k]:iu[k] + nv] = -Bt[k].T
        if k > 0:
            E[:, ix[k]:ix[k] + ns] = -At[k].T
        rows.append(E)
        rhs.append(b[k])
    for (k, i), val in (fixed_u or {}).items():
        e = np.zeros((1, n))
        e[0, iu[k] + i] = 1.0
        rows.append(e)
        rhs.append([val])
    E, e = np.vstack(rows), np.concatenate(rhs)
    kkt = np.block([[Hd, E.T], [E, np.zeros((E.shape[0], E.shape[0]))]])
    sol = np.linalg.solve(kkt, np.concatenate([-g, e]))
    z = sol[:n]
    return (np.array([z[iu[k]:iu[k] + nv] for k in range(N)]),
            np.array([z[ix[k]:ix[k] + ns] for k in range(1, N + 1)]))


@pytest.mark.parametrize("shim", [True, False])
def test_unconstrained_qp_matches_dense_kkt(shim):
    rng = np.random.default_rng(3)
    At, Bt, b, q, r, H, HN = _problem(rng)
    N, ns, nv = 4, 3, 2
    qp = hpipm.OcpQp(ns, nv, N, [0], shim=shim)
    qp.set_hessian(H, HN)
    big = np.full((N + 1, 1), 1e6)
    x, u, _ = qp.solve(At, Bt, b, q, r, -big, big, np.full((N, nv), -1e6),
                       np.full((N, nv), 1e6))
    assert qp.status == 0 and 0 < qp.iterations < 50
    u_ref, x_ref = _dense_kkt(At, Bt, b, q, r, H, HN)
    np.testing.assert_allclose(u, u_ref, atol=1e-6)
    np.testing.assert_allclose(x[1:], x_ref, atol=1e-6)
    np.testing.assert_array_equal(x[0], 0.0)                # stage 0 has no state


def test_active_input_bound_matches_pinned_kkt():
    rng = np.random.default_rng(5)
    At, Bt, b, q, r, H, HN = _problem(rng)
    N, ns, nv = 4, 3, 2
    u_free, _ = _dense_kkt(At, Bt, b, q, r, H, HN)
    bound = u_free[1, 0] - 0.5                              # cut the free optimum
    ubu = np.full((N, nv), 1e6)
    ubu[1, 0] = bound
    qp = hpipm.OcpQp(ns, nv, N, [0])
    qp.set_hessian(H, HN)
    big = np.full((N + 1, 1), 1e6)
    x, u, _ = qp.solve(At, Bt, b, q, r, -big, big, np.full((N, nv), -1e6), ubu)
    assert qp.status == 0
    u_ref, x_ref = _dense_kkt(At, Bt, b, q, r, H, HN, fixed_u={(1, 0): bound})
    np.testing.assert_allclose(u, u_ref, atol=1e-6)
    np.testing.assert_allclose(x[1:], x_ref, atol=1e-6)


def test_unknown_mode_is_named():
    with pytest.raises(ValueError, match="'fast'.*speed_abs"):
        hpipm.OcpQp(3, 2, 4, [0], mode="fast")


def test_shim_build_failure_falls_back_to_the_ctypes_loop(tmp_path, monkeypatch):
    """An unwritable cache directory: a warning, no shim, the QP still solves (ctypes loop)."""
    from trq_offboard.nmpc import cache
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the cache directory should be")
    monkeypatch.setenv("TRQ_CACHE_DIR", str(blocker / "cache"))
    monkeypatch.setattr(hpipm, "_SHIM", None)      # forget this process's shim (restored after)
    if cache.find_compiler() is not None:
        with pytest.warns(RuntimeWarning, match="trq_hpipm_shim"):
            qp = hpipm.OcpQp(3, 2, 4, [0])
    else:
        qp = hpipm.OcpQp(3, 2, 4, [0])
    assert not qp.uses_shim
    rng = np.random.default_rng(3)
    At, Bt, b, q, r, H, HN = _problem(rng)
    qp.set_hessian(H, HN)
    big = np.full((5, 1), 1e6)
    qp.solve(At, Bt, b, q, r, -big, big, np.full((4, 2), -1e6), np.full((4, 2), 1e6))
    assert qp.status == 0
    u_ref, _ = _dense_kkt(At, Bt, b, q, r, H, HN)
    np.testing.assert_allclose(qp.u, u_ref, atol=1e-6)


def _fake_blasfeo(tmp_path, cpu_ok: int) -> Path:
    """A libblasfeo.so whose processor check answers cpu_ok, beside a libhpipm.so path."""
    import subprocess

    from trq_offboard.nmpc import cache
    cc = cache.find_compiler()
    if cc is None:
        pytest.skip("no C compiler")
    src = tmp_path / "fake.c"
    src.write_text("#include <string.h>\n"
                   f"int blasfeo_processor_cpu_features(int *f) {{ *f = 0; return {cpu_ok}; }}\n"
                   "void blasfeo_processor_library_string(char *s) { strcpy(s, \"AVX2 FMA\"); }\n")
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(tmp_path / "libblasfeo.so"), str(src)],
                   check=True)
    return tmp_path / "libhpipm.so"


def test_another_build_needing_instructions_this_cpu_lacks_is_refused(tmp_path, monkeypatch):
    """The BLASFEO beside another build's libhpipm says this processor lacks what it was built
    for: the library is refused, naming the file and what it needs, before anything of it
    runs."""
    path = _fake_blasfeo(tmp_path, cpu_ok=0)
    monkeypatch.setattr(hpipm, "_mapped", lambda p: False)     # CasADi's not loaded yet
    with pytest.raises(OSError, match=r"lacks instructions .*libblasfeo.so.*AVX2 FMA"):
        hpipm._load_other(path)


def test_another_build_is_refused_where_casadis_own_is_loaded(tmp_path, monkeypatch):
    """CasADi's libhpipm already in the process (casadi.conic's plugin): another build, which
    shares its soname, is refused (the caller falls back to the bundled one)."""
    path = _fake_blasfeo(tmp_path, cpu_ok=1)
    monkeypatch.setattr(hpipm, "_mapped", lambda p: True)
    with pytest.raises(OSError, match="CasADi's own libhpipm is already loaded"):
        hpipm._load_other(path)


def test_conic_is_refused_while_another_build_is_in_use(monkeypatch, tmp_path):
    """casadi.conic('hpipm') would bind to another build's libhpipm by their common soname:
    a clear error instead of a crash; none with the bundled library."""
    hpipm.check_conic()                            # the bundled one (or none): allowed
    monkeypatch.setattr(hpipm, "_LIB", object())
    monkeypatch.setattr(hpipm, "_LIB_PATH", tmp_path / "libhpipm.so")
    with pytest.raises(RuntimeError, match=r"cannot run in a process that loaded .*TRQ_HPIPM"):
        hpipm.check_conic()


def test_the_library_label_names_the_one_a_process_loads(monkeypatch, tmp_path):
    """A run's record of its QP library: $TRQ_HPIPM_LIBRARY's when set, else CasADi's."""
    other = tmp_path / "libhpipm.so"
    monkeypatch.setenv(hpipm.LIBRARY_ENV, str(other))
    assert hpipm.library_label() == f"$TRQ_HPIPM_LIBRARY {other}"
    monkeypatch.delenv(hpipm.LIBRARY_ENV)
    bundled = hpipm.bundled_path()
    assert hpipm.library_label() == (f"CasADi's {bundled}" if bundled else "none found")
