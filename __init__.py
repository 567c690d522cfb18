"""hapticlab: plugin-based haptic teleoperation for robotic-surgery training.

The package is laid out by data flow: ``hapticlab.core`` (hookspecs, plugin
manager, data types, frames, estimator math), ``hapticlab.plugins`` (built-in
sensors, kinematics, estimators, haptic outputs, effects) and
``hapticlab.sessions`` (config, run loop, MCAP recording, command line).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("hapticlab")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"
