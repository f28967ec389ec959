"""Progress of long library steps (contact-map builds), reported to whoever asked for it.

The library never prints. A front end that wants a bar installs a factory with :func:`set_factory`
(``drivetrain``'s command line installs a tqdm bar with the cost model's estimate); the library asks
:func:`reporter` for an object with ``update(n)`` and ``close()`` and gets a silent one when nobody asked.
This module imports nothing heavy, so a command can install its factory before the numerical modules load.
"""
from __future__ import annotations

_FACTORY = None


class Silent:
    """A reporter that reports nothing."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def set_factory(factory) -> None:
    """Install (None: remove) the reporter factory: ``factory(desc, total, **info)`` returns an object with
    ``update(n)`` and ``close()`` (a tqdm bar fits). ``info`` of a contact-map build: ``triangles`` of the
    pair and ``workers`` (processes), for an estimate by ``gearcontact_fmu.cost.map_row_seconds``; of any
    other step (native builds, writing a run's files): ``unit`` (what is counted)."""
    global _FACTORY
    _FACTORY = factory


def reporter(desc: str, total: int, **info):
    """A progress reporter for ``total`` units of work (silent when no factory is installed)."""
    if _FACTORY is None:
        return Silent()
    return _FACTORY(desc, total, **info)
