"""The Modbus master engines (sans-IO): the exchange, the line guard, the poll plan, MBAP and RTU."""
