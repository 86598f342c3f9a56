"""The physics world: a coach on a track with real rail defects, simulated at the field rate.

``railwatch simulate`` writes its passes as recordings (:mod:`~railwatch.physics.files`); the
modules, from the bottom up: :mod:`~railwatch.physics.vehicle` (the coach),
:mod:`~railwatch.physics.track` (the rail on its supports), :mod:`~railwatch.physics.contact`
(Hertz's contact where the wheel lifts), :mod:`~railwatch.physics.dynamics` (the two coupled),
:mod:`~railwatch.physics.irregularity` (spectra), :mod:`~railwatch.physics.features` (defects and
features as rail geometry), :mod:`~railwatch.physics.world` (a track), and
:mod:`~railwatch.physics.passes` (a pass and its clean twin). Parameters, sources and checks:
``docs/physics.md``.
"""
