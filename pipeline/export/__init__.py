"""export: an identified model (``coefficients.json``) -> the files a lab's simulator or autopilot reads.

- :mod:`.model`: the identified model read back from ``coefficients.json`` (+ optional vessel config);
- :mod:`.vrx`: Gazebo / VRX ``usv_gazebo_dynamics_plugin`` SDF block;
- :mod:`.pvs`: a Python module whose vessel class runs in Fossen's PythonVehicleSimulator main loop;
- :mod:`.ardupilot`: ArduPilot Rover / boat parameters, clamped to their documented ranges;
- :mod:`.ros2`: a ROS 2 parameter YAML file;
- :mod:`.cli`: ``vesselid export``.
"""

from ..lazy import lazy_exports

#: Public name -> module defining it; loaded on first use, so ``vesselid export --help`` stays fast.
_EXPORTS = {
    "ExportModel": ".model", "model_from_coefficients": ".model",
    "FORMATS": ".formats", "export_text": ".writers", "write_export": ".writers",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
