"""Polygonal-contact (PCM) model of the rig's straight bevel pair, and its GearContact FMU.

The modules of this package are a pure library (geometry, contact, gear stage). The FMU slave
script in ``gearcontact_fmu/slaves`` is a thin shell over it and is never imported here.
"""

__version__ = "0.1.0"
