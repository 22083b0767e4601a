"""The DeviceNet wire format, sans-IO and stateless: identifiers, frames, CIP, explicit messages, fragmentation,
the Identity object and the I/O assemblies, shared by the master, the slave and the decoder."""
