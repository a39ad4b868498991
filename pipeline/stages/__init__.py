"""The stages and commands on top: one module per DVC stage or command (`track`, `associate`), each reading
its inputs, calling the wings below and writing its outputs; only `pipeline.cli` imports them."""
