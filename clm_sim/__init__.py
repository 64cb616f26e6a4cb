"""clm-sim: a 10 kHz simulation of a coreless linear motor and its feedforward identification."""

__version__ = "0.1.0"
