"""Policy learning from built datasets: robomimic-style BC-RNN, trained on the low-dim
observations a dataset stores, evaluated in our simulation and in plain robosuite.

Importing the package loads neither torch nor a simulator; the modules do."""
