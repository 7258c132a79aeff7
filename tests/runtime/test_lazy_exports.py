"""Package attributes imported on first use (runtime.lazy_exports), on the packages that use them."""
from __future__ import annotations

import subprocess
import sys

import pytest


def test_a_light_submodule_does_not_import_the_packages_heavy_ones():
    code = ("import sys, drivers.sim.motion, tools.calibrate.checks, models.emulated_da3.params; "
            "print([m for m in ('drivers.sim.recording', 'drivers.sim.render', 'tools.calibrate.core', "
            "'runtime.pipeline', 'drivers.live', 'drivers.euroc', 'drivers.uvc', 'drivers.rosbag', "
            "'models.emulated_da3.emulator', 'cv2') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_exports_are_the_submodules_own_values_listed_and_unknown_names_raise(monkeypatch):
    import drivers.sim
    import drivers.sim.motion
    import tools.calibrate
    from tools.calibrate.checks import Thresholds

    assert drivers.sim.PRESETS is drivers.sim.motion.PRESETS and tools.calibrate.Thresholds is Thresholds
    assert {"SimRecording", "write_euroc", "PRESETS"} <= set(dir(drivers.sim))
    assert set(drivers.sim.__all__) <= set(dir(drivers.sim))
    with monkeypatch.context() as m:     # not cached: a patched submodule is seen, and its undoing too
        m.setattr(drivers.sim.motion, "PRESETS", {"fake": None})
        assert drivers.sim.PRESETS == {"fake": None}
    assert drivers.sim.PRESETS is drivers.sim.motion.PRESETS and "euroc" in drivers.sim.PRESETS
    with pytest.raises(AttributeError, match="module 'drivers.sim' has no attribute 'nothing'"):
        drivers.sim.nothing  # noqa: B018
    # a package dropped from sys.modules (as reloading tools do) still lists its names
    monkeypatch.delitem(sys.modules, "drivers.sim")
    assert "SimRecording" in dir(drivers.sim) and "__name__" in dir(drivers.sim)


@pytest.mark.parametrize("package", ["drivers", "drivers.sim", "models.emulated_da3", "tools.calibrate"])
def test_every_listed_name_resolves_to_its_modules_value(package):
    import importlib

    pkg = importlib.import_module(package)
    exports = pkg._EXPORTS
    assert set(pkg.__all__) <= set(exports)
    for name, module in exports.items():
        assert getattr(pkg, name) is getattr(importlib.import_module(module), name), name
