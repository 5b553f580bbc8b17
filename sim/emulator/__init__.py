"""The rig emulator: the rig model of sim/ behind the UDP rig protocol, in real time, with fault injection.

What a lab's real-time I/O target runs, played by a process of its own (``isorig rig-emulator``):
``protocol`` is the wire format, ``server`` the real-time loop. Standard library and sim/ only.
"""
