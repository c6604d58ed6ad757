"""The one robot description: URDF, drive-train parameters, kinematics and dynamics.

Ground floor: imports no other package of this project.
"""
