"""SCADA over Modbus TCP: the register map (one table), the snapshot the server answers from, and
the pymodbus server inside the controller process. README, "SCADA: Modbus register map"."""
