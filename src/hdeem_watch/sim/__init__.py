"""The simulated node: a node with hidden truth to calibrate against (``source = "sim"``).

Its truth comes from its own generator, not from the calibrated model: page placement and a bank
hash unlike the model's, power-down, hot refresh, I/O energy, part variation, sensor gain/offset,
quantisation or RAPL energy units, aging; opaque jobs; the memory-controller counts of its hidden
commands. The power :class:`~hdeem_watch.sources.base.Source` over it is
:class:`hdeem_watch.sources.sim.SimSource`; the modules here know nothing of sources.

- :mod:`~hdeem_watch.sim.layout`: sockets, channels, DIMMs, sensors and memspec of the simulated node
  (the DDR5 node's memspec: ``ddr5_node.json``, docs/sources.md).
- :mod:`~hdeem_watch.sim.plan`: the truth generator (:class:`~hdeem_watch.sim.plan.TruthNode`).
- :mod:`~hdeem_watch.sim.traffic`, :mod:`~hdeem_watch.sim.power`: its controller view and DIMM states.
- :mod:`~hdeem_watch.sim.currents`, :mod:`~hdeem_watch.sim.age`: hidden currents and aging.
- :mod:`~hdeem_watch.sim.signal`, :mod:`~hdeem_watch.sim.fast`, :mod:`~hdeem_watch.sim.rapl`: readings.
- :mod:`~hdeem_watch.sim.truth`: the ``truth()`` report; :mod:`~hdeem_watch.sim.model`: the model side.
- :mod:`~hdeem_watch.sim.jobs`, :mod:`~hdeem_watch.sim.commands`: opaque jobs, hidden commands.
- :mod:`~hdeem_watch.sim.imc_events`, :mod:`~hdeem_watch.sim.counters`: what its IMC counters show.
"""
