"""The C generator: a policy's network as dependency-free C99 (`generate`, with its text helpers
`text` and the operation count `bench`; `gru`, PX4 mc_raptor's GRU policy), and the bare-metal
Cortex-M harness and QEMU runner (`harness`, `target`). quad-export writes its C with it; the
runtime's C backend compiles it."""
