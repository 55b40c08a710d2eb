"""ToosiCubix: 3D vehicle cuboids from part clicks in one monocular image."""

__version__ = "0.1.0"
