"""The physical models, one module each: path, motion, imu, uwb, availability.

Each module owns the pydantic class of its parameters and pure, vectorised functions of
(inputs, its own parameters, a numpy Generator). No model reads a file, knows the scenario as a
whole, or changes its inputs; :mod:`physynth.generate` composes them.
"""
