"""quad-export (torch + onnx): `cli`, the command; `onnx_export`, the deployable module and the
ONNX file with its metadata, golden vectors and parity checks; `c_export`, the same policy as C99
through `ccode`; `px4_raptor_export`, a px4-raptor policy as the files PX4's mc_raptor loads."""
