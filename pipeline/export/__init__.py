"""export: an identified model (``coefficients.json``) -> the files a lab's simulator or autopilot reads.

- :mod:`.model`: the identified model read back from ``coefficients.json`` (+ optional vessel config);
- :mod:`.vrx`: Gazebo / VRX ``usv_gazebo_dynamics_plugin`` SDF block;
- :mod:`.pvs`: a Python module whose vessel class runs in Fossen's PythonVehicleSimulator main loop;
- :mod:`.ardupilot`: ArduPilot Rover / boat parameters, clamped to their documented ranges;
- :mod:`.ros2`: a ROS 2 parameter YAML file;
- :mod:`.cli`: ``vesselid export``.
"""

from .model import ExportModel, model_from_coefficients
from .writers import FORMATS, export_text, write_export

__all__ = ["ExportModel", "model_from_coefficients", "FORMATS", "export_text", "write_export"]
