"""The node as it is: topology and DIMMs detected, the memspec for its DIMMs, its sensor map.

- :mod:`.description`: :class:`NodeDescription` and :func:`describe_node` (sysfs, EDAC, dmidecode).
- :mod:`.overrides`: the ``[node]`` TOML table (:func:`parse_node_table`, :func:`apply_overrides`).
- :mod:`.memspec_choice`: DIMM → memspec (:func:`choose_memspec`).
- :mod:`.sensors`: sensor → DIMMs (:func:`sensor_map`).
- :mod:`.report`: the whole picture as one JSON object (``hdeem-watch node --json``).
- :mod:`.setup`: what the daemon models (description, memspec with reason, topology, sensors).
"""
