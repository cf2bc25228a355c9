"""trq_lab.reporting: every report the experiment layer writes, and one cell formatter.

What goes in: flights' metrics and rows (a scenario's runs, a campaign's rows, result
directories). What comes out: Markdown (report.md, the README's generated blocks), the figures
beside it and the summaries (metrics.json). It flies nothing.

    fmt             one table cell's text (`fmt`), for every report below (standard library only)
    plot            matplotlib with its file backend, chosen once, for every report's figures
    scenario        a scenario's report.md table and figures (trq-scenario, trq-inprocess)
    campaign        a campaign's report: success and RMSE against fault and wind, heat maps,
                    where each controller stops coping, metrics.json (trq-campaign)
    plant_campaign  a campaign with a plant axis: the flights against each plant's faulted trim
                    (envelope classes, rank correlations, paired comparison, targets)
    results         the README's results tables, generated from result files (trq-results;
                    standard library only)
    lost_motor      figures of flights with a motor lost: height, thrust axis tilt, yaw rate,
                    drift from the failure
    logcsv          the controller daemon's ULog as its CSV log, on the ground (trq-log-csv)
"""
