"""The MAVLink contract: messages, fields, units, frames (NED/FRD on the wire), signing; the
transport (one receive point per link), .tlog writing and the impairment proxy."""
