"""The MAVLink contract: messages, fields, units, frames (NED/FRD on the wire), signing."""
