"""Decision risk of an intervention from a calibrated model (seed §4.4.2, eq. 23): ``bpsflow decide``."""
