"""An independent forward model of the two-lens polarisation-multiplexed thermal camera (:mod:`.forward`), written
without the package's simulator, and the tests and grid that measure the reconstruction on its recordings."""
