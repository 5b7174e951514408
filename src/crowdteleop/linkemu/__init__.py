"""A user-space link emulator, as Cellsim and Mahimahi are (this kernel has no `tc netem`):
two network namespaces, a TUN device in each, a forwarder applying per-direction rate or a
Mahimahi trace, one-way delay, a drop-tail queue and random loss (docs/network.md)."""
