"""The components of the calibrated model, one module per physical effect or part of the scenario.

Each module holds its fit's report section and parameters and a ``COMPONENT``
(:class:`~physynth.calibrate.component.Component`: name, what it fits, the components it needs, its
fit); :data:`physynth.calibrate.pipeline.COMPONENTS` lists them in dependency order.
"""
