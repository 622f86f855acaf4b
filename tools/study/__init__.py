"""Studies at scale: sweeps over scenario keys and seeds, batches of recordings."""
