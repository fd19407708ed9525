"""4 million stored photons fit in 1 GB through passes 1 and 2 (issue 3), measured in a fresh process."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1]); sys.path.insert(0, sys.argv[1] + "/tests")
import pdic_bootstrap; pdic_bootstrap.load()
import numpy as np
from scenes import geometry, quad
from pdic.core.executor import Executor
from pdic.core.density import PhotonDensity
from pdic.core.irradiance_cache import CacheParameters, cache_from_photons
from pdic.core.photons import PhotonMap, trace_photons
from pdic.core.rays import RayCaster
from pdic.core.scene import Materials, PointLight, Scene, recentre

# A closed unit box (normals inward) with albedo 0.7 and a point light: 9 bounces store ~3.2 photons each.
tris = np.concatenate([quad([0, 0, 0], [0, 1, 0], [1, 0, 0]), quad([0, 0, 1], [1, 0, 0], [0, 1, 0]),
                       quad([0, 0, 0], [1, 0, 0], [0, 0, 1]), quad([0, 1, 0], [0, 0, 1], [1, 0, 0]),
                       quad([0, 0, 0], [0, 0, 1], [0, 1, 0]), quad([1, 0, 0], [0, 1, 0], [0, 0, 1])])
local, origin = recentre(tris)
scene = Scene(geometry(local), Materials(("wall",), np.full((1, 3), 0.7), np.array([-1]), np.zeros((1, 3))),
              lights=(PointLight("lamp", np.array([0, 0, 0.3]), np.full(3, 10.0)),), origin_world=origin)
photons, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 1_240_000, 9, seed=0, executor=Executor(2))
cache, _, _, _ = cache_from_photons(PhotonDensity(photons), CacheParameters(0.4, 16, 0.03, 0.17), seed=0)
# VmHWM: the peak resident set of this process's own address space. (ru_maxrss would not do: Linux
# carries the pre-exec high-water mark into it, so it reports at least the parent's size at fork.)
hwm_kb = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:"))
print(json.dumps({"stored": len(photons), "records": len(cache), "bytes_per_photon": PhotonMap.BYTES_PER_PHOTON,
                  "peak_mb": hwm_kb / 1024}))
"""


@pytest.mark.slow
def test_four_million_photons_fit_in_one_gigabyte_through_pass_2():
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(ROOT)], capture_output=True, text=True, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["stored"] >= 4_000_000
    assert result["records"] > 0
    assert result["bytes_per_photon"] == 101
    assert result["peak_mb"] <= 1024  # the whole process: interpreter, numpy, Embree, kd-tree, cache
