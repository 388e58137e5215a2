"""Hardware and its stand-ins: the serial pattern trigger, the V4L2 camera, the emulator, the replay and
simulated devices. Consumers depend on the protocols in `drivers.base`, never on a concrete driver."""
