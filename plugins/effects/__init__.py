"""The built-in effect models of the discrepancy workflow, one module per effect.

Each module registers one effect through ``register_effects``; an effect is
written against ``hapticlab.core.sensor_model`` (``Effect``, ``ModelState``,
``Motion``). What each models, and what tells it from the others:
``docs/discrepancy.md``.
"""
