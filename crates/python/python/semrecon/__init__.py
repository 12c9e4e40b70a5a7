"""placeholder"""
from ._native import *  # noqa
