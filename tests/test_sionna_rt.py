"""Sionna RT channel provider: a small street scene traced in 3-D in a child process (skips
when the optional ``radioloc[rt]`` extra or a suitable LLVM library is absent), the refusal
of an LLVM too old for Dr.Jit, and the install hint when absent."""

import importlib.metadata

import numpy as np
import pytest
from isolated import run_isolated
from sionna_checks import RX, SCENE, TX

from radioloc.channel import sionna_rt
from radioloc.channel.raytrace import trace_links_cached
from radioloc.core.errors import ConfigError

OK, WHY = sionna_rt.check_requirements()          # loads nothing native
needs_sionna = pytest.mark.skipif(not OK, reason=f"Sionna RT unavailable: {WHY}")


@needs_sionna
def test_sionna_traces_los_reflections_and_through_wall_paths(tmp_path):
    run_isolated("sionna_checks:street_scene", tmp_path)


def test_an_abort_in_the_child_is_one_failed_test_with_its_last_lines():
    with pytest.raises(pytest.fail.Exception, match=r"(?s)SIGABRT.*last words"):
        run_isolated("sionna_checks:crash", "last words")


def test_llvm_older_than_the_minimum_is_refused_naming_it(tmp_path, monkeypatch):
    fake = tmp_path / "libLLVM-15.so"
    fake.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(fake))
    assert sionna_rt.llvm_version(str(fake)) == 15
    with pytest.raises(ConfigError, match=r"LLVM 15.*needs LLVM >= 19.*libllvm19"):
        sionna_rt.llvm_library()
    ok, why = sionna_rt.check_requirements()
    assert not ok and "LLVM 15" in why
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "absent.so"))
    with pytest.raises(ConfigError, match="DRJIT_LIBLLVM_PATH: no file"):
        sionna_rt.llvm_library()


def test_llvm_version_read_from_the_library_name(tmp_path):
    for name, version in (("libLLVM-14.0.6.so.1", 14), ("libLLVM.so.19.1", 19),
                          ("libLLVM-16.so", 16)):
        (tmp_path / name).write_bytes(b"")
        assert sionna_rt.llvm_version(str(tmp_path / name)) == version
    (tmp_path / "libLLVM.so").symlink_to(tmp_path / "libLLVM.so.19.1")
    assert sionna_rt.llvm_version(str(tmp_path / "libLLVM.so")) == 19


def test_missing_sionna_raises_config_error_with_install_hint(monkeypatch):
    real = importlib.metadata.version

    def version(dist):
        if dist == "sionna-rt":
            raise importlib.metadata.PackageNotFoundError(dist)
        return real(dist)

    monkeypatch.setattr(importlib.metadata, "version", version)
    ok, why = sionna_rt.check_requirements()
    assert not ok and "radioloc[rt]" in why and "libllvm19" in why
    with pytest.raises(ConfigError, match=r"radioloc\[rt\]"):
        trace_links_cached(SCENE, TX, RX, sionna_rt.SionnaConfig(), cache_dir="/nonexistent")


def test_sionna_config_validated():
    with pytest.raises(ConfigError, match="max_depth"):
        sionna_rt.SionnaConfig(max_depth=-1)
    with pytest.raises(ConfigError, match="antenna_height_m"):
        sionna_rt.SionnaConfig(antenna_height_m=30.0, building_height_m=20.0)
    with pytest.raises(ConfigError, match="config"):
        trace_links_cached(SCENE, TX, RX, object(), cache_dir="/nonexistent")


def test_prism_mesh_is_closed_with_outward_normals():
    v, f = sionna_rt.prism_mesh_arrays(SCENE, 20.0)
    tri = v[f].astype(float)                                   # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    u = n / np.linalg.norm(n, axis=1, keepdims=True)
    centre = tri.mean(axis=1)

    def solid(p):                                              # inside a building's volume
        return SCENE.inside(p[:, :2]) & (p[:, 2] > 0) & (p[:, 2] < 20.0)

    # every normal points out of the solid: a step against it is inside, along it outside
    assert solid(centre - 0.01 * u).all() and not solid(centre + 0.01 * u).any()
    # closed: every edge is shared by exactly two triangles
    e = np.round(v[np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])], 4)   # (E, 2, 3)
    first = [tuple(a) <= tuple(b) for a, b in zip(e[:, 0].tolist(), e[:, 1].tolist())]
    keyed = np.where(np.array(first)[:, None, None], e, e[:, ::-1]).reshape(len(e), -1)
    _, counts = np.unique(keyed, axis=0, return_counts=True)
    assert np.all(counts == 2)
