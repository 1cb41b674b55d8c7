"""Sim2Real transfer benchmark harness: will this policy transfer?"""

__version__ = "0.1.0"
