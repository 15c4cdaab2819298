"""Sites on separate hosts on one machine: a Linux network namespace per site, linked by veth
pairs to a bridge, addresses in 198.18.0.0/15 only (:mod:`~bintrack.hosts.site_network`), made and
removed with iproute2 (:mod:`~bintrack.hosts.netns`). ``bintrack up --regions N --hosts`` runs each
region's router and services in its site's namespace."""
