"""POWERLINK-timed CiA 402 telegrams over python-can.

Ground floor: imports no other package of this project.
"""
