"""Camera emulators for tests and benchmarks without hardware (a GigE Vision camera for Aravis).
"""
