"""The machinery below the algorithm: matmul paths, compiled programs and process settings.

Nothing here knows about spiking networks or TD3: :mod:`ilcsan.snn` and :mod:`ilcsan.rl` import this package, and
it imports neither.
"""
