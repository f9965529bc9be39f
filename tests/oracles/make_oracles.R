# Oracle fixtures for tightscan-core (crates/tightscan-core/src/detectors/monitor.rs and cusum.rs).
#
# Run once, from anywhere:  Rscript tests/oracles/make_oracles.R
# Needs the Debian packages r-base-core, r-cran-strucchange and r-cran-spc. Writes plain-text
# fixtures next to this script; the Rust tests read those committed files and never need R.
#
# (a) strucchange_<case>.csv: OLS-CUSUM monitoring by strucchange::mefp with a custom border
#     matching tightscan's boundary. strucchange's monitoring process is
#         process(K) = cumsum_{i<=K} e_i / (sigma_m sqrt(m)),   K = m+1..n,
#     e_i = y_i - x_i' beta_m (training OLS fit), sigma_m^2 = RSS_m / (m - p). The training
#     residuals sum to 0 (intercept), so process(m + k) = Q(m, k) / (sigma_m sqrt(m)), and the
#     tightscan rule |Q| >= sigma_m c sqrt(m) (1 + k/m) (k/(m+k))^gamma becomes
#         |process(K)| > border(K) = c (K/m) ((K - m)/K)^gamma.
#     strucchange alarms on '>' and reports the 1-based K; tightscan on '>=' and reports the
#     0-based index K - 1 (ties have probability 0).
#     Header lines '# key = value' give m, gamma, c, the breakpoint and the maximum |process|;
#     the table has one row per observation: index (1-based), y, regressors, process, border
#     (NA during training).
# (b) spc_xcusum_arl.csv: zero-state ARL of the CUSUM for normal data, spc::xcusum.arl(k, h, mu,
#     sided) by the Nystroem method, with r = 100 quadrature nodes (default 30) so that the
#     fixture is exact to far below the 0.5 % the test allows.

suppressMessages({
  library(strucchange)
  library(spc)
})

args <- commandArgs(trailingOnly = FALSE)
script <- sub("^--file=", "", args[grep("^--file=", args)])
out_dir <- if (length(script) == 1) dirname(normalizePath(script)) else "."

num <- function(x) ifelse(is.na(x), "NA", sprintf("%.17g", x))

ols_cusum_case <- function(name, n, m, regressors, beta, shift_at, shift, gamma, critval, seed) {
  set.seed(seed)
  X <- matrix(runif(n * regressors, 0, 10), nrow = n, ncol = regressors)
  if (regressors > 0) colnames(X) <- paste0("x", seq_len(regressors))
  mu <- beta[1] + if (regressors > 0) X %*% beta[-1] else 0
  y <- as.vector(mu) + rnorm(n)
  if (!is.na(shift_at)) y[shift_at:n] <- y[shift_at:n] + shift
  full <- if (regressors > 0) data.frame(y = y, X) else data.frame(y = y)
  fml <- if (regressors > 0) as.formula(paste("y ~", paste(colnames(X), collapse = " + "))) else y ~ 1
  border <- function(K) critval * (K / m) * ((K - m) / K)^gamma
  me <- mefp(fml, type = "OLS-CUSUM", data = full[1:m, , drop = FALSE], border = border)
  mo <- monitor(me, data = full, verbose = FALSE)
  process <- c(rep(NA, m), as.vector(mo$process))
  bord <- c(rep(NA, m), border((m + 1):n))
  file <- file.path(out_dir, paste0("strucchange_", name, ".csv"))
  con <- file(file, "w")
  writeLines(c(
    "# strucchange::mefp(type = \"OLS-CUSUM\", border = function(K) c * (K/m) * ((K - m)/K)^gamma)",
    sprintf("# strucchange version = %s", as.character(packageVersion("strucchange"))),
    sprintf("# m = %d", m),
    sprintf("# regressors = %d", regressors),
    sprintf("# gamma = %s", num(gamma)),
    sprintf("# critical_value = %s", num(critval)),
    sprintf("# sigma = %s", num(sqrt(sum(lm.fit(cbind(1, X[1:m, , drop = FALSE]), y[1:m])$residuals^2) / (m - 1 - regressors)))),
    sprintf("# breakpoint = %s", ifelse(is.na(mo$breakpoint), "NA", as.character(mo$breakpoint))),
    sprintf("# statistic = %s", num(mo$statistic)),
    paste(c("index", "y", colnames(X), "process", "border"), collapse = ",")
  ), con)
  rows <- sapply(seq_len(n), function(i) {
    paste(c(as.character(i), num(y[i]), if (regressors > 0) num(X[i, ]) else NULL, num(process[i]), num(bord[i])),
          collapse = ",")
  })
  writeLines(rows, con)
  close(con)
  cat(name, ": breakpoint", mo$breakpoint, "statistic", mo$statistic, "\n")
}

# Slope-and-intercept model, intercept shift of 1.5 sigma at observation 200.
ols_cusum_case("p2_shift", n = 300, m = 100, regressors = 1, beta = c(1, 0.5), shift_at = 200,
               shift = 1.5, gamma = 0.25, critval = 2.3860, seed = 101)
# Mean only, no change: the process must match, and no alarm.
ols_cusum_case("p1_null", n = 400, m = 150, regressors = 0, beta = c(3), shift_at = NA,
               shift = 0, gamma = 0.45, critval = 2.80, seed = 202)
# Two regressors, early change, gamma = 0 (the Brownian-motion boundary).
ols_cusum_case("p3_early", n = 250, m = 80, regressors = 2, beta = c(-2, 0.3, 1.2), shift_at = 100,
               shift = -1.0, gamma = 0.0, critval = 2.2414, seed = 303)

# (b) CUSUM ARLs.
grid <- expand.grid(mu = c(0, 0.25, 0.5, 1, 2), h = c(2, 3, 4, 5, 8), k = c(0.25, 0.5, 1),
                    sided = c("one", "two"), stringsAsFactors = FALSE)
grid$arl <- mapply(function(k, h, mu, sided) xcusum.arl(k, h, mu, sided = sided, r = 100),
                   grid$k, grid$h, grid$mu, grid$sided)
con <- file(file.path(out_dir, "spc_xcusum_arl.csv"), "w")
writeLines(c(
  "# spc::xcusum.arl(k, h, mu, sided, r = 100): zero-state ARL, alarm when S > h, N(mu, 1) data",
  sprintf("# spc version = %s", as.character(packageVersion("spc"))),
  "kappa,h,mu,sided,arl"
), con)
writeLines(sprintf("%s,%s,%s,%s,%s", num(grid$k), num(grid$h), num(grid$mu), grid$sided, num(grid$arl)), con)
close(con)
cat("spc: ", nrow(grid), "ARLs\n")
