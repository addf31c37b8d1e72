"""Pure estimation math shared by stations and aircraft: UT, Kalman steps, geometry, CRLB."""
