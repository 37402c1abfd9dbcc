"""The daemon's shell: the service loop and the threads and sockets around the pure run book."""
