"""Bus drivers that connect the runtime to vehicles and HMIs: CAN (python-can) and Modbus TCP (pymodbus)."""
