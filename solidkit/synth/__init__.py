"""SOLID-Img-style synthetic data and a virtual field campaign (Mitsuba 3).

Modules: :mod:`~solidkit.synth.renderer` (variant selection), :mod:`~solidkit.synth.plugins`
(our pinhole/equirect sensors and the buffers integrator), :mod:`~solidkit.synth.materials`
(84 material categories), :mod:`~solidkit.synth.scene` (procedural city blocks; the scene
frame), :mod:`~solidkit.synth.lighting` (sunsky and HDR maps; Mitsuba's envmap axes),
:mod:`~solidkit.synth.cameras` (cameras, best view per sector), :mod:`~solidkit.synth.sample`
(one sample), :mod:`~solidkit.synth.dataset` (sharded generation, index, torch Dataset),
:mod:`~solidkit.synth.filter` (colour-histogram filter), :mod:`~solidkit.synth.campaign` and
:mod:`~solidkit.synth.exif` (the virtual field campaign), :mod:`~solidkit.cli.synth`.
Mitsuba is imported lazily (on first render), so importing this package is cheap.
"""
