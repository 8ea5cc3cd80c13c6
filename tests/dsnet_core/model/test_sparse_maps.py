"""Kernel maps against brute force, their reuse across layers and backward, and the fast paths
(dense index table vs searchsorted, compressed rows, skinny-GEMM fusion) against the plain ones."""

import itertools

import pytest
import torch
import torch.nn.functional as F

from dsnet_core.model import sparse_conv as sc
from dsnet_core.model import sparse_index as si
from dsnet_core.model import sparse_maps as sm
from dsnet_core.model.backbone import AsymmetricUNet
from dsnet_core.model.sparse_conv import SparseTensor, SubMConv3d
from tests.dsnet_core.model.test_sparse_conv import dense_weight, gather, make, random_sites, to_dense

TOL = dict(atol=1e-10, rtol=1e-10)
torch.set_num_threads(1)  # the machines behave like one core; extra threads only spin


def brute_pairs(coords, kernel):
    """{tap: {(in, out)}} of a submanifold kernel by comparing every pair of sites."""
    site = {tuple(c.tolist()): i for i, c in enumerate(coords)}
    out = {}
    for t, d in enumerate(itertools.product(*(range(k) for k in kernel))):
        e = [d[a] - kernel[a] // 2 for a in range(3)]
        out[t] = {
            (site[(b, i + e[0], j + e[1], k + e[2])], o)
            for o, (b, i, j, k) in enumerate(coords.tolist())
            if (b, i + e[0], j + e[1], k + e[2]) in site
        }
    return out


def book_pairs(book, n_taps):
    return {t: set(zip(i.tolist(), o.tolist(), strict=True)) for t, (i, o) in enumerate(book.pairs(n_taps))}


@pytest.mark.parametrize("kernel", [(3, 3, 3), (1, 3, 3), (3, 1, 1), (5, 3, 1)])
@pytest.mark.parametrize("dense", [True, False])
def test_neighbour_map_matches_brute_force(kernel, dense, monkeypatch):
    if not dense:  # force the searchsorted path
        monkeypatch.setattr(si, "DENSE_TABLE_MAX_CELLS", 0)
    coords = random_sites((7, 6, 5), 2, 150, seed=11)
    nmap = sm.NeighbourMap.build(coords, (7, 6, 5), (2, 1, 1), 2)  # a box larger than some kernels
    book = nmap.rulebook(kernel)
    n_taps = kernel[0] * kernel[1] * kernel[2]
    assert book_pairs(book, n_taps) == brute_pairs(coords, kernel)
    assert book.identity == n_taps // 2


def test_submanifold_kernels_of_one_level_share_one_search(monkeypatch):
    calls = []
    build = sm.NeighbourMap.build.__func__
    monkeypatch.setattr(
        sm.NeighbourMap, "build", classmethod(lambda cls, *a: calls.append(1) or build(cls, *a))
    )
    x = make((6, 5, 4), 1, 60, 2, seed=3)
    for k in [(1, 3, 3), (3, 1, 3), (3, 3, 3), (3, 1, 1)]:
        x = SubMConv3d(2, 2, k).double()(x)
    assert len(calls) == 1 and len(x.cache.subm) == 4
    books = list(x.cache.subm.values())
    assert all(b.table is books[0].table for b in books)


def test_backbone_builds_each_map_once_for_forward_and_backward(monkeypatch):
    counts = {"subm": 0, "strided": 0, "csr": 0}
    build, strided, csr = sm.NeighbourMap.build.__func__, sc.strided_rulebook, sm.PairTable.csr

    def count(name, fn):
        def wrapped(*a, **k):
            counts[name] += 1
            return fn(*a, **k)

        return wrapped

    def counting_csr(self, side, cols):
        if (side, cols) not in self._csr:
            counts["csr"] += 1
        return csr(self, side, cols)

    monkeypatch.setattr(sm.NeighbourMap, "build", classmethod(count("subm", build)))
    monkeypatch.setattr(sc, "strided_rulebook", count("strided", strided))
    monkeypatch.setattr(sm.PairTable, "csr", counting_csr)
    torch.manual_seed(0)
    net = AsymmetricUNet(in_channels=3, width=2).double()
    coords = random_sites((16, 16, 8), 1, 400, seed=5)
    x = SparseTensor(torch.randn(coords.shape[0], 3, dtype=torch.float64), coords, (16, 16, 8), 1)
    out = net(x)
    after_forward = dict(counts)
    out.features.square().sum().backward()
    assert counts["subm"] == 5  # one neighbour search per resolution
    assert counts["strided"] == 4
    # the backward adds compressed rows by input only; no map is rebuilt
    assert counts["subm"] == after_forward["subm"] and counts["strided"] == after_forward["strided"]
    assert counts["csr"] > after_forward["csr"]


def test_compressed_rows_group_pairs_by_site():
    coords = random_sites((6, 6, 4), 1, 90, seed=2)
    book = sm.NeighbourMap.build(coords, (6, 6, 4), (1, 1, 1), 1).rulebook((1, 3, 3))
    plain = sm.PairTable(book.table.in_idx, book.table.out_idx, book.table.starts, book.table.counts, 90, 90)
    for side in ("out", "in"):
        rows, offsets = book.csr(side)
        ref_rows, ref_offsets = plain.csr(side, book.cols)  # without the mirror shortcut
        assert torch.equal(offsets, ref_offsets)
        idx = book.out_idx if side == "out" else book.in_idx
        bounds = [*offsets.tolist(), rows.numel()]
        for s in range(90):
            got = sorted(rows[bounds[s] : bounds[s + 1]].tolist())
            ref = sorted(ref_rows[bounds[s] : bounds[s + 1]].tolist())
            assert got == ref and all(idx[r] == s for r in got)


@pytest.mark.parametrize("cout", [4, 8, 2])
def test_skinny_outputs_fused_rows_match_dense(cout):
    """C_out < 16 takes the block-diagonal GEMM; enough sites for full and remainder rows."""
    shape = (9, 8, 6)
    x = make(shape, 1, 300, 3, seed=cout)
    torch.manual_seed(4)
    layer = SubMConv3d(3, cout, 3).double()
    y = layer(x)
    ref = gather(F.conv3d(to_dense(x.features, x.coords, shape, 1), dense_weight(layer), padding=1), x.coords)
    torch.testing.assert_close(y.features, ref, **TOL)
    g = torch.randn_like(ref)
    got = torch.autograd.grad((y.features * g).sum(), (x.features, layer.weight))
    exp = torch.autograd.grad((ref * g).sum(), (x.features, layer.weight))
    for a, b in zip(got, exp, strict=True):
        torch.testing.assert_close(a, b, **TOL)


def test_scratch_made_in_inference_mode_serves_training():
    sc.release_workspace()
    x = make((6, 5, 4), 1, 50, 2, seed=8)
    layer = SubMConv3d(2, 3, 3).double()
    with torch.inference_mode():
        ref = layer(SparseTensor(x.features.detach(), x.coords, x.shape, 1)).features.clone()
    y = layer(x)
    torch.testing.assert_close(y.features.detach(), ref, **TOL)
    y.features.sum().backward()
    assert layer.weight.grad is not None


def test_strided_map_matches_brute_force():
    coords = random_sites((7, 6, 3), 2, 80, seed=9)
    book, out_coords, out_shape = sm.strided_rulebook(coords, (7, 6, 3), (3, 3, 3), (2, 2, 1), (1, 1, 1))
    assert out_shape == (4, 3, 3)
    out_site = {tuple(c.tolist()): i for i, c in enumerate(out_coords)}
    expect = {}
    for t, d in enumerate(itertools.product(range(3), range(3), range(3))):
        expect[t] = set()
        for q, (b, *p) in enumerate(coords.tolist()):
            num = [p[a] + 1 - d[a] for a in range(3)]
            s = (2, 2, 1)
            if all(n % s[a] == 0 and 0 <= n // s[a] < out_shape[a] for a, n in enumerate(num)):
                expect[t].add((q, out_site[(b, *(n // s[a] for a, n in enumerate(num)))]))
    assert book_pairs(book, 27) == expect
    assert set(out_site.values()) == set(range(out_coords.shape[0]))


def _table_state(table):
    return (table.in_idx, table.out_idx, table.starts, table.counts, table.n_in, table.n_out, table.mirror)


def _same_tables(a, b):
    for x, y in zip(_table_state(a), _table_state(b), strict=True):
        if isinstance(x, torch.Tensor):
            assert x.dtype == y.dtype and torch.equal(x, y)
        else:
            assert x == y


@pytest.mark.parametrize("radius", [(1, 1, 1), (2, 1, 1), (0, 1, 1)])
def test_cpu_loops_build_the_torch_neighbour_map_pair_for_pair(radius, monkeypatch):
    coords = random_sites((7, 6, 5), 3, 400, seed=21)
    fast = sm.NeighbourMap.build(coords, (7, 6, 5), radius, 3)
    monkeypatch.setattr(sm, "CPU_KERNELS", False)
    ref = sm.NeighbourMap.build(coords, (7, 6, 5), radius, 3)
    _same_tables(fast.table, ref.table)
    for side in ("in", "out"):
        cols = tuple(range(len(ref.table.counts)))
        got, want = fast.table.csr(side, cols), ref.table.csr(side, cols)
        assert all(torch.equal(g, w) for g, w in zip(got, want, strict=True))
    # the scratch table is left as it was found
    assert torch.all(si.scratch_table(1 << 12, coords.device) == -1)


@pytest.mark.parametrize(
    "stride,shape", [((2, 2, 2), (7, 6, 5)), ((2, 2, 1), (9, 6, 3)), ((1, 2, 3), (5, 5, 7))]
)
def test_cpu_loops_build_the_torch_strided_map_pair_for_pair(stride, shape, monkeypatch):
    coords = random_sites(shape, 2, 300, seed=5)
    fast, fast_coords, fast_shape = sm.strided_rulebook(coords, shape, (3, 3, 3), stride, (1, 1, 1), 2)
    cols = tuple(range(27))
    fast_csr = [fast.table.csr(side, cols) for side in ("in", "out")]
    monkeypatch.setattr(sm, "CPU_KERNELS", False)
    ref, ref_coords, ref_shape = sm.strided_rulebook(coords, shape, (3, 3, 3), stride, (1, 1, 1), 2)
    _same_tables(fast.table, ref.table)
    assert torch.equal(fast_coords, ref_coords) and fast_shape == ref_shape
    for got, side in zip(fast_csr, ("in", "out"), strict=True):
        want = ref.table.csr(side, cols)
        assert all(torch.equal(g, w) for g, w in zip(got, want, strict=True))
    assert torch.all(si.scratch_table(1 << 12, coords.device) == -1)
