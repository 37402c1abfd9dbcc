"""The state database: the one schema owner, its one writer thread, checks, repair and the store worker."""
