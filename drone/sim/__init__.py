"""The simulated AR.Drone 2.0: ``physics`` + ``battery`` (flight model), ``drone`` (``SimDrone``,
the sans-I/O wire core), ``link`` (``InMemoryLink`` for lockstep), ``server`` (``SimServer`` on
real loopback sockets, ``run_sim``), ``world`` and ``camera`` (rooms, fields, rendering)."""
